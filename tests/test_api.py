"""The Python API (``neuralbrdf.read``, ``fit``, ``export``, ``load``, ``truth``, ``evaluate``,
``render_image``): a light import, every kind of source, fits through the shipped configs, clear
errors, and the end-to-end example.  (Each function's docstring example runs as a doctest too.)"""

import json
import math
import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import neuralbrdf as nb
from neuralbrdf.api.fitting import _data_options
from neuralbrdf.data.gcms import write_gcms
from neuralbrdf.data.merl_binary import write_merl
from neuralbrdf.errors import FitFailed, InputError
from neuralbrdf.virtual import instrument

pytestmark = pytest.mark.filterwarnings("ignore:LightningCLI's args parameter is intended")
REPO = Path(__file__).resolve().parents[1]
NBRDF = REPO.parent / "shared" / "data" / "merl-nbrdf" / "nylon.h5"
HEAVY = ("torch", "mitsuba", "drjit", "pytorch_lightning", "onnxruntime")
QUICK_ABC = {"model.n_starts": 1, "data.eval_plan": None}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A MERL file (a blue diffuse term and a white ABC-like lobe), a GCMS session and a spectral table."""
    folder = tmp_path_factory.mktemp("api")
    theta_h = (np.arange(90)[:, None, None] + 0.5) ** 2 / 90.0  # MERL's cell centres: i_h = floor(sqrt(90 θh))
    lobe = 2.0 / (1.0 + 200.0 * (1.0 - np.cos(np.radians(theta_h)))) ** 2 * np.ones((90, 90, 180))
    write_merl(np.array([0.1, 0.2, 0.4])[:, None, None, None] / math.pi + lobe[None], folder / "blue.binary")
    device = instrument.VirtualGoniospectrophotometer(noise_rel=0.0, seed=0)
    for name in ("cyan", "munsell_n9"):
        write_gcms(device.measure_plan(name, "DS2"), folder / f"{name}.csv")
    assert nb.read("virtual:gold").samples is not None
    from neuralbrdf.data.table import write_table

    write_table(nb.read(folder / "cyan.csv", folder / "munsell_n9.csv").samples, folder / "cyan_table.csv")
    return folder


def test_import_neuralbrdf_loads_neither_torch_nor_mitsuba():
    code = ("import sys, neuralbrdf as nb; nb.read; nb.fit; nb.render_image; nb.FIT_KINDS; nb.InputError; "
            f"print([m for m in {HEAVY!r} if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO).stdout
    assert out.strip() == "[]"
    assert {"read", "fit", "export", "load", "truth", "evaluate", "render_image"} <= set(dir(nb))
    with pytest.raises(AttributeError):
        nb.no_such_name


def test_read_every_kind_of_source(files):
    table = nb.read(files / "cyan_table.csv")
    gcms = nb.read(files / "cyan.csv", files / "munsell_n9.csv")
    merl = nb.read(files / "blue.binary", plan="DS3")
    virtual = nb.read("virtual:gonio")
    assert (table.kind, gcms.kind, merl.kind, virtual.kind) == ("table", "gcms", "merl", "virtual")
    assert table.samples.n_rows == gcms.samples.n_rows == 185 and table.is_spectral and gcms.is_spectral
    assert merl.samples.n_rows == 57 and not merl.is_spectral and merl.plan == "DS3" and merl.name == "blue"
    assert np.all(merl.samples.values >= np.array([0.1, 0.2, 0.4]) / math.pi)
    assert nb.read(files / "blue.binary").plan == "DS1"
    assert [s.has_truth for s in (table, gcms, merl, virtual)] == [False, False, True, True]
    assert gcms.options() == {"path": str(files / "cyan.csv"), "reference": str(files / "munsell_n9.csv")}


@pytest.mark.skipif(not NBRDF.is_file(), reason="../shared/data/merl-nbrdf is absent")
def test_read_an_nbrdf_proxy():
    nylon = nb.read(NBRDF, plan="DS4")
    assert (nylon.kind, nylon.name, nylon.samples.n_rows) == ("nbrdf", "nylon", 6)
    assert nylon.options() == {"nbrdf": str(NBRDF), "plan": "DS4"}


@pytest.mark.parametrize("call, message", [
    (lambda f: nb.read(f / "cyan_table.csv", plan="DS2"), "applies to NBRDF (.h5), MERL (.binary) and RGL (.bsdf) files"),
    (lambda f: nb.read("virtual:gold", f / "munsell_n9.csv"), "a Munsell reference goes with a GCMS raw file"),
    (lambda f: nb.read(f / "blue.binary", plan="DS9"), "unknown plan 'DS9'"),
    (lambda f: nb.read(f / "cyan.csv"), "is a GCMS raw file"),
    (lambda f: nb.read(f / "missing.csv"), "missing.csv"),
    (lambda f: nb.fit("mlp", "virtual:gold"), "unknown fit kind 'mlp'; expected one of auto, abc, spectral_mlp, nlb, nlb_spectral, pca"),
    (lambda f: nb.truth(nb.read(f / "cyan_table.csv"), f / "t.onnx"), "a measurement (table) is known only where"),
    (lambda f: nb.evaluate("m.onnx", "t.onnx", f / "e", material="gold"), "give the scene too"),
    (lambda f: nb.evaluate("m.onnx", "t.onnx", f / "e", spp=0), "spp must be a positive integer"),
    (lambda f: nb.render_image(None, f / "x.png"), "render a model or a built-in reference BSDF"),
    (lambda f: nb.render_image("m.onnx", f / "x.jpg"), "the output must be a .png file"),
], ids=["plan for a table", "reference for virtual", "bad plan", "GCMS without reference", "missing file",
        "unknown kind", "truth of a measurement", "material without scene", "zero spp", "nothing to render",
        "not a png"])
def test_bad_input_is_one_input_error(files, call, message):
    with pytest.raises(InputError) as error:
        call(files)
    assert message in str(error.value) and "\n" not in str(error.value)


@pytest.mark.parametrize("call, argument", [
    (lambda f: nb.read(123), "source"),
    (lambda f: nb.read(None), "source"),
    (lambda f: nb.read(f / "cyan.csv", reference=5), "reference"),
    (lambda f: nb.read("virtual:gold", name=3), "name"),
    (lambda f: nb.fit("abc", 5), "data"),
    (lambda f: nb.fit("abc", "virtual:gold", config=5), "config"),
    (lambda f: nb.fit("abc", "virtual:gold", run_dir=5), "run_dir"),
    (lambda f: nb.fit("abc", "virtual:gold", overrides=["trainer.max_epochs=5"]), "overrides"),
    (lambda f: nb.load(None), "path"),
    (lambda f: nb.export(None, f / "x.onnx"), "checkpoint"),
    (lambda f: nb.export(f / "x.ckpt", 3), "out"),
    (lambda f: nb.truth(None, f / "x.onnx"), "source"),
    (lambda f: nb.truth("virtual:gold", None), "out"),
    (lambda f: nb.evaluate(None, f / "t.onnx", f / "e"), "model"),
    (lambda f: nb.evaluate(f / "m.onnx", 7, f / "e"), "truth"),
    (lambda f: nb.evaluate(f / "m.onnx", f / "t.onnx", None), "out_dir"),
    (lambda f: nb.evaluate(f / "m.onnx", f / "t.onnx", f / "e", spp="8"), "spp"),
    (lambda f: nb.evaluate(f / "m.onnx", f / "t.onnx", f / "e", scene=1), "scene"),
    (lambda f: nb.render_image(3), "model"),
    (lambda f: nb.render_image(f / "m.onnx", 3), "out"),
    (lambda f: nb.render_image(f / "m.onnx", spp=2.5), "spp"),
    (lambda f: nb.render_image(f / "m.onnx", seed=-1), "seed"),
    (lambda f: nb.render_image(f / "m.onnx", variant=None), "variant"),
    (lambda f: nb.read(f / "cyan_table.csv", trust_units="yes"), "trust_units"),
    (lambda f: nb.fit(["abc"]), "unknown fit kind"),
    (lambda f: nb.fit("abc", "virtual:gold", overwrite="no"), "overwrite"),
    (lambda f: nb.export(f / "x.ckpt", f / "x.onnx", fast="no"), "fast"),
    (lambda f: nb.export(f / "x.ckpt", f / "x.onnx", rgb_head=0), "rgb_head"),
    (lambda f: nb.export(f / "x.ckpt", f / "x.onnx", config=None), "config"),
    (lambda f: nb.evaluate(f / "m.onnx", f / "t.onnx", f / "e", images="no"), "images"),
    (lambda f: nb.evaluate(f / "m.onnx", f / "t.onnx", f / "e", backend=1), "backend"),
    (lambda f: nb.render_image(f / "m.onnx", exr="yes"), "exr"),
    (lambda f: nb.render_image(f / "m.onnx", rgb_tolerance="0.01"), "rgb_tolerance"),
    (lambda f: nb.design_plan(3, max_theta="60"), "max_theta"),
    (lambda f: nb.next_pairs("virtual:gold", step=float("nan")), "step"),
    (lambda f: nb.acquire("virtual:gold", render="no"), "render"),
    (lambda f: nb.view(f / "m.onnx", port="x"), "port"),
    (lambda f: nb.view(f / "m.onnx", host=127), "host"),
])
def test_an_argument_of_the_wrong_type_is_an_input_error_naming_it(files, call, argument):
    """``nb.read(123)`` and ``nb.evaluate(None, …)`` raised a bare TypeError from pathlib."""
    with pytest.raises(InputError) as error:
        call(files)
    assert str(error.value).startswith(argument), str(error.value)


def test_truths_type_error_names_every_kind_of_source_it_takes():
    with pytest.raises(InputError, match="a MERL .binary or an RGL .bsdf"):
        nb.truth(123, "x.onnx")


def test_a_model_refuses_wavelengths_outside_its_range_and_directions_that_are_not_finite(tmp_path):
    """0.55 (µm), -5 and 1e9 nm were clamped to the nearest end of the range, a NaN direction gave 0."""
    gold = nb.truth("virtual:gold", tmp_path / "gold.onnx")
    up = np.array([0.0, 0.0, 1.0])
    assert gold(up, up, 400.0).shape == gold(up, up, 700.0).shape == (1,)
    for nm in (0.55, -5.0, 1e9, float("nan"), 399.9):
        with pytest.raises(InputError, match=r"wavelength .* nm is outside gold.onnx's range 400-700 nm"):
            gold(up, up, nm)
    with pytest.raises(InputError, match="wavelength 800 nm is outside"):
        gold(np.stack([up, up]), np.stack([up, up]), [550.0, 800.0])
    for bad in (np.nan, np.inf):
        with pytest.raises(InputError, match=r"wo: direction 1 is not finite"):
            gold(np.stack([up, up]), np.array([up, [bad, 0.0, 1.0]]), 550.0)
        with pytest.raises(InputError, match=r"wi: direction 0 is not finite"):
            gold(np.array([[0.0, bad, 1.0]]), up, 550.0)


def test_a_model_scored_against_itself_is_said_as_the_command_says_it(tmp_path):
    """``nb.evaluate(m, m, out)`` scored 0 silently; every note of the scores is a warning in
    Python as on the command line."""
    from onnx_fixtures import write_lambert

    model = write_lambert(tmp_path / "m.onnx")
    with pytest.warns(UserWarning, match="are the same model .*every error is 0 by construction"):
        scores = nb.evaluate(model, model, tmp_path / "e", images=False)
    assert scores["notes"] and "same model" in scores["notes"][0]


def test_every_fit_kind_names_a_shipped_config():
    from neuralbrdf.configs_dir import resolve_config

    assert set(nb.FIT_KINDS) == {"auto", "abc", "spectral_mlp", "nlb", "nlb_spectral", "pca"}
    assert all(resolve_config(config).is_file() for config in nb.FIT_KINDS.values())


def test_a_source_goes_to_the_data_module_in_its_own_vocabulary(files):
    merl, virtual = nb.read(files / "blue.binary", plan="DS2"), nb.read("virtual:gold")
    gcms = nb.read(files / "cyan.csv", files / "munsell_n9.csv")
    assert _data_options("abc", merl) == {"data.merl": str(files / "blue.binary"), "data.plan": "DS2"}
    assert _data_options("spectral_mlp", gcms) == {"data.path": str(files / "cyan.csv"),
                                                   "data.reference": str(files / "munsell_n9.csv")}
    assert _data_options("nlb_latent", virtual) == _data_options("nlb_spectral", virtual) == {
        "data.sources": [{"virtual": "gold"}]}
    with pytest.raises(InputError, match="the spectral_mlp config's data module takes path, reference, virtual; "
                                         ".*blue.binary is a merl source"):
        _data_options("spectral_mlp", merl)


def test_a_fit_runs_through_the_config_and_exports(files, tmp_path):
    threads = torch.get_num_threads()
    result = nb.fit("abc", nb.read(files / "blue.binary", plan="DS2"), run_dir=tmp_path / "run", overrides=QUICK_ABC)
    assert result.kind == "abc" and result.checkpoint == tmp_path / "run" / "checkpoints" / "best.ckpt"
    assert result.metrics["status"] == "ok" and result.metrics["fit/abc/success"] is True
    assert torch.get_num_threads() == threads  # the config's num_threads: 1 held for the run only
    config = (tmp_path / "run" / "config.yaml").read_text()
    assert "AbcFitModule" in config and "n_starts: 1" in config and "blue.binary" in config and "plan: DS2" in config
    model = result.export(tmp_path / "blue.onnx")
    assert (model.kind, model.material, model.is_spectral) == ("abc", "blue", False)
    wi = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    f = model(wi, wi * [-1, -1, 1])
    assert f.shape == (2, 3) and np.all(f > 0)
    with pytest.raises(InputError, match="already holds a run"):
        nb.fit("abc", "virtual:gold", run_dir=tmp_path / "run", overrides=QUICK_ABC)


def test_a_failed_fit_raises_fit_failed_and_leaves_no_best_checkpoint(tmp_path):
    with pytest.raises(FitFailed, match="no start converged"):
        nb.fit("abc", "virtual:gold", run_dir=tmp_path / "run",
               overrides={**QUICK_ABC, "model.max_evaluations": 3})
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["status"] == "failed"
    assert not list((tmp_path / "run").rglob("best*.ckpt"))


def test_a_model_checks_its_inputs(tmp_path):
    gold = nb.truth("virtual:gold", tmp_path / "gold.onnx")
    up = np.array([0.0, 0.0, 1.0])
    assert gold(up, up, 550.0).shape == (1,)
    with pytest.raises(InputError, match="spectral: give a wavelength"):
        gold(up, up)
    with pytest.raises(InputError, match=r"wi and wo must both be \[N, 3\]"):
        gold(np.ones((2, 2)), np.ones((2, 2)), 550.0)
    with pytest.raises(InputError, match="must be numbers"):
        gold("up", up, 550.0)
    with pytest.raises(InputError, match="one number or 1"):
        gold(up, up, [500.0, 600.0])


@pytest.mark.slow
def test_the_end_to_end_example_runs_in_reduced_form(tmp_path, monkeypatch, capsys):
    """``examples/api_end_to_end.py --quick``: read -> fit -> export -> evaluate -> render (~30 s of CPU)."""
    monkeypatch.setattr(sys, "argv", ["api_end_to_end.py", "--quick", "--out-dir", str(tmp_path)])
    runpy.run_path(str(REPO / "examples" / "api_end_to_end.py"), run_name="__main__")
    out = capsys.readouterr().out
    for step in ("read gold", "fit:", "export:", "evaluate:", "render: 32x32"):
        assert step in out, out
    scores = json.loads((tmp_path / "eval" / "evaluation.json").read_text())
    assert scores["model_kind"] == "spectral_mlp" and scores["truth_material"] == "gold"
    assert (tmp_path / "gold.png").stat().st_size > 0 and (tmp_path / "eval" / "comparison.png").is_file()
