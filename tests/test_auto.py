"""The ``auto`` fit and kind (docs/models.md#auto): the better of ABC and the spectral NLB on the
measured pairs, exported as that candidate's graph with the choice in the file."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import neuralbrdf as nb
from neuralbrdf import kinds
from neuralbrdf.data.plans import plan_spherical
from neuralbrdf.data.table import BrdfTable, write_table
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import spherical_to_vector
from neuralbrdf.kinds import auto as auto_kind
from neuralbrdf.lightning.auto_fit import AutoFitModule, choose
from neuralbrdf.metrics import hemisphere_logcos_rmse
from neuralbrdf.physics.abc import AbcParameters

QUIET = {"trainer.enable_progress_bar": False, "data.eval_plan": None}
#: A glossy ABC material (RGB): a table of it is ABC's own form, fitted exactly by ABC.
GLOSSY = AbcParameters(kd=np.array([0.3, 0.2, 0.1]), A=np.array([2.0, 2.5, 3.0]), B=400.0, C=0.8, eta=1.5)


def _table(values_of, plan: str = "DS2") -> BrdfTable:
    angles = plan_spherical(plan)
    wi, wo = spherical_to_vector(angles[0], angles[1]), spherical_to_vector(angles[2], angles[3])
    return BrdfTable(*angles, values_of(wi, wo), source=f"test table on {plan}")


@pytest.fixture(scope="module")
def abc_table(tmp_path_factory):
    path = tmp_path_factory.mktemp("auto") / "glossy_abc.csv"
    write_table(_table(GLOSSY.evaluate), path)
    return path


@pytest.fixture(scope="module")
def abc_choice(tmp_path_factory, abc_table):
    """An auto fit of a table of ABC's own form, and its export."""
    folder = tmp_path_factory.mktemp("auto_abc")
    result = nb.fit("auto", abc_table, run_dir=folder / "run", overrides=QUIET)
    return result, result.export(folder / "auto.onnx", rgb_head=False)


# --------------------------------------------------------------------------- the choice


def test_choose_takes_the_lower_error_among_the_candidates_that_fitted():
    assert choose({"abc": 0.02, "nlb_spectral": 0.01}) == "nlb_spectral"
    assert choose({"abc": 0.01, "nlb_spectral": 0.02}) == "abc"
    assert choose({"abc": 0.01, "nlb_spectral": 0.01}) == "abc"  # a tie: the analytic model
    assert choose({"abc": None, "nlb_spectral": 0.5}) == "nlb_spectral"
    assert choose({"abc": 0.01, "nlb_spectral": math.nan}) == "abc"
    assert choose({"abc": None, "nlb_spectral": math.nan}) is None


def test_a_table_of_abcs_own_form_chooses_abc_and_the_file_is_that_abc(abc_choice, abc_table):
    result, model = abc_choice
    metrics = result.metrics
    assert metrics["status"] == "ok" and metrics["fit/auto/choice"] == "abc"
    errors = metrics["fit/auto/inplane_logcos_rmse"]
    assert errors["abc"] < 1e-3 < errors["nlb_spectral"]  # ABC recovers its own form; the prior does not exactly
    assert model.kind == "auto" and not model.is_spectral
    # the in-plane error the choice was made on is the file's own, recomputed from the table
    table = nb.read(abc_table).samples
    wi, wo = table.vectors()
    f = model(wi, wo)
    assert hemisphere_logcos_rmse(f, table.values, table.theta_i) == pytest.approx(errors["abc"], rel=1e-3, abs=1e-6)
    # and the graph is the fitted ABC's
    fitted = AbcParameters.from_dict(metrics["fit/auto/abc_parameters"], source="metrics")
    assert np.allclose(f, fitted.evaluate(wi, wo), rtol=1e-4, atol=1e-6)


def test_the_file_says_what_it_chose_and_samples_with_the_chosen_kinds_proposal(abc_choice):
    _, model = abc_choice
    loaded = kinds.load_model(model.path)
    details = loaded.details
    assert details.choice == "abc" and details.proposal == "abc_lobe"
    assert details.chosen_details.B == float(loaded.metadata["neuralbrdf.auto.abc.B"]) > 0
    assert json.loads(loaded.metadata[auto_kind.ERRORS_KEY]) == details.inplane_logcos_rmse
    assert set(details.inplane_logcos_rmse) == {"abc", "nlb_spectral"}
    assert not kinds.get("auto").fast_default(loaded.metadata)  # an ABC graph renders at analytic cost already


def test_the_viewers_file_table_shows_the_choice(abc_choice):
    from neuralbrdf.explorer.models import ViewedModel

    described = ViewedModel.load(abc_choice[1].path, "auto.onnx").describe()
    assert described["kind"] == "auto" and described["metadata"]["neuralbrdf.auto.choice"] == "abc"


def test_the_chosen_proposal_is_the_chosen_kinds_own():
    from neuralbrdf.render.sampling import fit_proposal

    import neuralbrdf.render.sampling as sampling

    details = auto_kind.AutoMetadata("abc", {}, "abc_lobe", object())
    seen = []
    original = sampling.PROPOSALS["abc_lobe"]
    try:
        sampling.PROPOSALS["abc_lobe"] = lambda brdf, d: seen.append(d) or "lobe"
        assert fit_proposal("chosen", None, details) == "lobe"
    finally:
        sampling.PROPOSALS["abc_lobe"] = original
    assert seen == [details.chosen_details]


def test_a_surface_without_a_lobe_is_fitted_by_the_prior_and_says_why_not_abc(tmp_path):
    table = _table(lambda wi, wo: np.full((len(wi), 3), 0.2))
    path = tmp_path / "lambertian.csv"
    write_table(table, path)
    result = nb.fit("auto", path, run_dir=tmp_path / "run", overrides=QUIET)
    assert result.metrics["fit/auto/choice"] == "nlb_spectral"
    assert result.metrics["fit/auto/inplane_logcos_rmse"]["abc"] is None
    assert "no specular lobe" in result.metrics["fit/auto/abc_failure"]
    model = result.export(tmp_path / "auto.onnx", fast=False)
    assert kinds.load_model(model.path).details.choice == "nlb_spectral"
    assert kinds.get("auto").fast_default(kinds.load_model(model.path).metadata)  # as the spectral NLB's files


def test_when_neither_candidate_fits_the_fit_fails_without_a_best_checkpoint(tmp_path, monkeypatch, abc_table):
    def no_nlb(self, table):
        self.errors["nlb_spectral"] = math.nan

    def no_abc(self, table):
        self.abc_failure = "test: no ABC"

    monkeypatch.setattr(AutoFitModule, "_fit_nlb", no_nlb)
    monkeypatch.setattr(AutoFitModule, "_fit_abc", no_abc)
    with pytest.raises(nb.FitFailed, match="neither candidate fitted"):
        nb.fit("auto", abc_table, run_dir=tmp_path / "run", overrides=QUIET)
    assert not (tmp_path / "run" / "checkpoints" / "best.ckpt").exists()


def test_a_bad_candidate_config_is_refused_before_the_fit(tmp_path, abc_table):
    with pytest.raises(InputError, match="config"):
        nb.fit("auto", abc_table, run_dir=tmp_path / "run", overrides={**QUIET, "model.abc_config": "nlb_spectral"})
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_the_abc_candidate_takes_its_configs_settings_with_the_auto_fits_own_number_of_starts():
    from neuralbrdf.lightning.config_models import abc_settings

    shipped = abc_settings("abc")
    assert AutoFitModule(abc_starts=None)._abc_arguments == shipped
    two = AutoFitModule(abc_starts=2)._abc_arguments
    assert two["n_starts"] == 2 and {k: v for k, v in two.items() if k != "n_starts"} == \
        {k: v for k, v in shipped.items() if k != "n_starts"}
    for bad in (0, 1.5, True):
        with pytest.raises(InputError) as error:
            AutoFitModule(abc_starts=bad)
        assert error.value.key == "model.abc_starts"


# --------------------------------------------------------------------------- the file's metadata


def _metadata(**changes):
    base = {auto_kind.CHOICE_KEY: "abc", auto_kind.ERRORS_KEY: '{"abc": 0.01, "nlb_spectral": 0.02}',
            "neuralbrdf.auto.abc.kd": "[0.1, 0.1, 0.1]", "neuralbrdf.auto.abc.A": "[1, 1, 1]",
            "neuralbrdf.auto.abc.B": "10.0", "neuralbrdf.auto.abc.C": "1.0", "neuralbrdf.auto.abc.eta": "1.5"}
    base.update(changes)
    return {k: v for k, v in base.items() if v is not None}


def test_the_metadata_reader_takes_a_good_file_and_names_the_key_of_a_bad_one():
    details = auto_kind.read_metadata(_metadata(), "m.onnx", False)
    assert details.choice == "abc" and details.chosen_details.eta == 1.5
    for changes, key in (({auto_kind.CHOICE_KEY: None}, auto_kind.CHOICE_KEY),
                         ({auto_kind.CHOICE_KEY: "spectral_mlp"}, auto_kind.CHOICE_KEY),
                         ({auto_kind.ERRORS_KEY: "[1, 2]"}, auto_kind.ERRORS_KEY),
                         ({auto_kind.ERRORS_KEY: '{"abc": "low"}'}, auto_kind.ERRORS_KEY),
                         ({"neuralbrdf.auto.abc.B": "-1"}, "neuralbrdf.auto.abc.B")):
        with pytest.raises(InputError) as error:
            auto_kind.read_metadata(_metadata(**changes), "m.onnx", False)
        assert error.value.key == key and "m.onnx" in str(error.value)
    with pytest.raises(InputError, match="lacks metadata keys"):
        auto_kind.read_metadata(_metadata(**{"neuralbrdf.auto.abc.C": None}), "m.onnx", False)


def test_an_auto_file_renders_as_its_candidates_file_does(abc_choice, tmp_path):
    """Same graph, same proposal (the ABC lobe), same seed: the same image as the abc kind's file."""
    pytest.importorskip("mitsuba")
    result, model = abc_choice
    fitted = AbcParameters.from_dict(result.metrics["fit/auto/abc_parameters"], source="metrics")
    from neuralbrdf.kinds import abc as abc_kind
    from neuralbrdf.onnx_export import write_model

    abc_file = write_model(abc_kind.exportable(fitted, "glossy", "test"), tmp_path / "abc.onnx").path
    settings = {"spp": 4, "resolution": 16, "variant": "llvm_ad_rgb"}
    auto_image = nb.render_image(model, **settings)
    abc_image = nb.render_image(nb.load(abc_file), **settings)
    assert np.all(np.isfinite(auto_image)) and auto_image.max() > 0
    assert np.allclose(auto_image, abc_image, rtol=1e-4, atol=1e-5)
