"""Measuring a fraction of the pairs (docs/how-many-measurements.md): the instrument's candidates,
the greedy Bayesian design against direct computation, the Jacobians against finite differences,
``plan next`` and ``acquire`` through the command line."""

import itertools
import json

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from neuralbrdf.acquisition import linear_design
from neuralbrdf.acquisition.instrument import Instrument, canonical_pairs, pair_keys
from neuralbrdf.acquisition.linear_design import (LinearisedProblem, expected_errors, greedy_design,
                                                  posterior_covariance)
from neuralbrdf.acquisition.next_pairs import interval
from neuralbrdf.acquisition.settings import load_acquisition_config
from neuralbrdf.cli.main import main
from neuralbrdf.data.plans import in_plane_plan
from neuralbrdf.errors import InputError


def run(*args):
    return main([str(a) for a in args])


def orbit(ti, tr):
    """The in-plane pairs one isotropic, reciprocal BRDF value is measured at (mirror and reciprocity)."""
    return {(ti, tr), (tr, ti), (-ti, -tr), (-tr, -ti)}


@pytest.mark.parametrize("max_theta, step, band", [(60.0, 1.0, 0.0), (60.0, 5.0, 12.0), (40.0, 10.0, 0.0),
                                                   (30.0, 2.5, 7.5)])
def test_the_candidates_are_one_pair_per_measurable_orbit_counted_by_brute_force(max_theta, step, band):
    instrument = Instrument(max_theta, step, band)
    ti, tr = instrument.candidates()
    n = int(round(max_theta / step))
    grid = [step * k for k in range(-n, n + 1)]
    orbits = {frozenset(orbit(a, b)) for a in grid for b in grid if abs(a + b) >= band - 1e-9}
    assert len(ti) == len(orbits)
    assert {frozenset(orbit(a, b)) for a, b in zip(ti.tolist(), tr.tolist())} == orbits
    assert np.all(ti >= np.abs(tr)) and np.all(np.abs(ti + tr) >= band - 1e-9)
    if (max_theta, step, band) == (60.0, 1.0, 0.0):
        assert len(ti) == 61 ** 2                 # theta_i 0..60, theta_r -theta_i..theta_i


@settings(max_examples=60, deadline=None)
@given(st.integers(-60, 60), st.integers(-60, 60))
def test_every_pair_of_an_orbit_has_one_key(a, b):
    keys = pair_keys(*map(np.array, zip(*orbit(float(a), float(b)))))
    assert len({tuple(k) for k in keys}) == 1
    ti, tr = canonical_pairs([a], [b])
    assert (ti[0], tr[0]) in orbit(float(a), float(b)) and ti[0] >= abs(tr[0])


@pytest.mark.parametrize("limits, key", [((60.0, 70.0, 0.0), "--step"), ((90.0, 1.0, 0.0), "--max-theta"),
                                         ((60.0, 0.0, 0.0), "--step"), ((60.0, 1.0, -1.0), "--retro-band"),
                                         ((60.0, float("nan"), 0.0), "--step"), ((60.0, True, 0.0), "--step")])
def test_impossible_instrument_limits_name_their_option(limits, key):
    with pytest.raises(InputError) as error:
        Instrument(*limits)
    assert error.value.key == key


def test_limits_that_leave_no_pair_say_so():
    with pytest.raises(InputError, match="leave no pair to measure"):
        Instrument(10.0, 5.0, 25.0).candidates()      # |theta_i + theta_r| reaches 20 at most


def random_problem(seed, materials=3, candidates=7, values=2, dimension=4):
    generator = torch.Generator().manual_seed(seed)
    jacobians = torch.randn(materials, candidates, values, dimension, generator=generator, dtype=torch.float64)
    a = torch.randn(materials, dimension, dimension, generator=generator, dtype=torch.float64)
    b = torch.randn(materials, dimension, dimension, generator=generator, dtype=torch.float64)
    eye = torch.eye(dimension, dtype=torch.float64)
    return LinearisedProblem(jacobians, a @ a.transpose(1, 2) + 0.1 * eye, b @ b.transpose(1, 2) + 0.1 * eye)


def criterion_of(problem, chosen):
    """Mean over materials of tr(H P(S)), P(S) by a direct inverse of the information matrix."""
    if not chosen:
        return float(expected_errors(problem.covariance, problem.hemisphere).mean())
    posterior = posterior_covariance(problem.covariance, problem.jacobians[:, list(chosen)])
    return float(expected_errors(posterior, problem.hemisphere).mean())


@pytest.mark.parametrize("seed", range(4))
def test_each_greedy_step_takes_the_best_pair_and_its_criterion_is_the_direct_posteriors(seed):
    problem = random_problem(seed)
    design = greedy_design(problem, 3)
    for step in range(3):
        before = design.chosen[:step]
        options = [c for c in range(7) if c not in before]
        best = min(options, key=lambda c: criterion_of(problem, before + [c]))
        assert design.chosen[step] == best
        assert design.criterion[step + 1] == pytest.approx(criterion_of(problem, design.chosen[:step + 1]), rel=1e-9)
    torch.testing.assert_close(design.covariance, posterior_covariance(problem.covariance,
                                                                       problem.jacobians[:, design.chosen]))
    assert design.criterion == sorted(design.criterion, reverse=True)


def test_greedy_is_near_the_best_subset_found_by_brute_force():
    problem = random_problem(11, candidates=8)
    best = min(criterion_of(problem, list(s)) for s in itertools.combinations(range(8), 3))
    greedy = greedy_design(problem, 3).criterion[-1]
    assert best <= greedy + 1e-12 and greedy <= 1.2 * best


def test_the_lazy_greedy_step_chooses_what_the_full_one_does(monkeypatch):
    problem = random_problem(5, materials=4, candidates=40)
    lazy = greedy_design(problem, 12)
    monkeypatch.setattr(linear_design, "LAZY_CANDIDATES", 10_000)   # every gain evaluated at every step
    full = greedy_design(problem, 12)
    assert lazy.chosen == full.chosen
    monkeypatch.setattr(linear_design, "BATCH_ENTRIES", 7)          # batches of a few materials and candidates
    assert greedy_design(problem, 12).chosen == full.chosen


def test_without_repeats_a_budget_beyond_the_candidates_is_refused_and_with_them_a_pair_may_return():
    problem = random_problem(2, candidates=3)
    with pytest.raises(ValueError, match="needs as many candidates"):
        greedy_design(problem, 4)
    assert len(greedy_design(problem, 6, allow_repeats=True).chosen) == 6


@pytest.fixture(scope="module")
def linearisation():
    from neuralbrdf.acquisition.nlb_linear import SpectralNlbLinearisation
    from neuralbrdf.lightning.nlb_spectral_module import load_spectral_pretrained
    from neuralbrdf.shipped import SPECTRAL_DEFAULT, resolve_pretrained

    pretrained = load_spectral_pretrained(resolve_pretrained(None, SPECTRAL_DEFAULT))
    weights = torch.tensor([[1.0, 0.0], [0.4, 0.6], [0.0, 1.0]])        # three channels from two node codes
    theta = torch.cat([pretrained.shared[3], pretrained.channels[3][:2].reshape(-1)])
    return SpectralNlbLinearisation(pretrained.network, weights), theta


def test_the_jacobians_are_the_finite_differences_of_the_values(linearisation):
    from neuralbrdf.geometry import inplane_to_vectors

    model, theta = linearisation
    wi, wo = (torch.as_tensor(v, dtype=torch.float32) for v in inplane_to_vectors(np.array([10.0, 45.0, 30.0]), np.array([10.0, 40.0, -20.0])))
    jacobians = model.jacobians(theta, wi, wo)
    assert jacobians.shape == (3, 3, model.dimension)
    eps = 1e-2
    for d in range(0, model.dimension, max(1, model.dimension // 7)):
        step = torch.zeros(model.dimension)
        step[d] = eps
        difference = (model.values(theta + step, wi, wo) - model.values(theta - step, wi, wo)) / (2 * eps)
        torch.testing.assert_close(jacobians[..., d], difference, rtol=0.05, atol=2e-4)


def test_the_estimate_is_the_spread_scaled_by_the_calibrated_quantiles():
    estimate = load_acquisition_config().estimate
    answer = interval(0.01, estimate.logcos_quantiles)
    low, middle, high = estimate.logcos_quantiles
    assert (answer.low, answer.estimate, answer.high) == pytest.approx(0.01 * np.exp([low, middle, high]))
    assert answer.low < answer.estimate < answer.high


def test_an_acquisition_config_names_the_file_and_key_it_refuses(tmp_path):
    text = (load_acquisition_config().path).read_text()
    for bad, key in ((text.replace("  seed: 0\n\nestimate", "  seed: 0\n  speed: 2\n\nestimate"), "design.speed"),
                     (text.replace("blends: 60", "blends: lots"), "design.blends"),
                     (text + "extra: {}\n", "extra")):
        path = tmp_path / "acq.yaml"
        path.write_text(bad)
        with pytest.raises(InputError) as error:
            load_acquisition_config(path)
        assert error.value.key == key and str(path) in str(error.value)


def test_the_shipped_six_pair_design_is_a_plan_of_six_measurable_orbits():
    theta_i, theta_r = in_plane_plan("configs/plans/nlb_spectral_6.csv")
    assert len(theta_i) == 6 == len({tuple(k) for k in pair_keys(theta_i, theta_r)})
    assert Instrument().measurable(theta_i, theta_r).all()


def one_line_error(capsys, *args, expect):
    assert run(*args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expect in err, err


def test_plan_design_refuses_impossible_budgets_in_one_line(tmp_path, capsys):
    out = tmp_path / "plan.csv"
    one_line_error(capsys, "plan", "design", "--budget", 0, "--out", out, expect="--budget")
    one_line_error(capsys, "plan", "design", "--budget", 5000, "--out", out, expect="from 1 to 3721")
    one_line_error(capsys, "plan", "design", "--budget", 3, "--max-theta", 0.5, "--out", out, expect="--step")
    one_line_error(capsys, "plan", "design", "--budget", 3, "--kind", "merl", "--out", out, expect="--kind")
    assert not out.exists()


def quick_config(tmp_path):
    """The shipped settings, designing over the measured proxies only, on a coarse hemisphere."""
    text = load_acquisition_config().path.read_text()
    path = tmp_path / "quick.yaml"
    path.write_text(text.replace("blends: 60", "blends: 0").replace("analytic: 60", "analytic: 0")
                    .replace("hemisphere_strata: [8, 10]", "hemisphere_strata: [3, 4]"))
    return path


def test_plan_design_writes_a_plan_of_the_instruments_pairs_that_a_fit_reads(tmp_path, capsys):
    out = tmp_path / "plan.csv"
    assert run("plan", "design", "--budget", 3, "--step", 15, "--retro-band", 20, "--config", quick_config(tmp_path),
               "--out", out) == 0
    assert "designed for nlb_spectral: 3 pairs" in capsys.readouterr().out
    theta_i, theta_r = in_plane_plan(out)
    assert len(theta_i) == 3 == len({tuple(k) for k in pair_keys(theta_i, theta_r)})
    assert Instrument(60.0, 15.0, 20.0).measurable(theta_i, theta_r).all()
    assert set(np.abs(np.concatenate([theta_i, theta_r])) % 15) == {0.0}


def test_plan_next_chooses_pairs_not_measured_and_says_whether_a_target_is_met(tmp_path, capsys):
    table = tmp_path / "ds4.csv"
    assert run("sample", "virtual:val-blue", "--plan", "DS4", "--out", table) == 0
    out = tmp_path / "next.csv"
    assert run("plan", "next", table, "--count", 3, "--step", 5, "--target-de", 0.01, "--out", out) == 0
    said = capsys.readouterr().out
    assert "6 pairs measured" in said and "measure these next" in said and "80 % interval" in said
    chosen = in_plane_plan(out)
    measured = {tuple(k) for k in pair_keys(*in_plane_plan("DS4"))}
    assert len(chosen[0]) == 3
    assert not measured & {tuple(k) for k in pair_keys(*chosen)}
    one_line_error(capsys, "plan", "next", table, "--count", 10_000, "--step", 5, "--out", tmp_path / "n2.csv",
                   expect="--count")
    one_line_error(capsys, "plan", "next", table, "--target-de", -1, "--out", tmp_path / "n3.csv", expect="--target-de")
    assert not (tmp_path / "n2.csv").exists() and not (tmp_path / "n3.csv").exists()


def test_plan_next_answers_for_a_table_measured_out_of_the_plane(tmp_path, capsys):
    table = tmp_path / "out_of_plane.csv"
    table.write_text("theta_i,phi_i,theta_o,phi_o,R,G,B\n30,0,40,90,0.1,0.1,0.1\n30,0,20,120,0.1,0.1,0.1\n")
    assert run("plan", "next", table, "--step", 10, "--out", tmp_path / "n.csv") == 0
    assert "2 pairs measured" in capsys.readouterr().out and len(in_plane_plan(tmp_path / "n.csv")[0]) == 1


@pytest.mark.slow
def test_acquire_writes_its_curve_and_refuses_to_overwrite_it(tmp_path, capsys):
    out = tmp_path / "session"
    args = ("acquire", "virtual:val-orange", "--start", "DS4", "--max", 8, "--count", 2, "--step", 10, "--no-render",
            "--out-dir", out)
    assert run(*args) == 0
    said = capsys.readouterr().out
    assert "stopped after 8 pairs: the budget of 8 pairs is spent" in said
    session = json.loads((out / "acquire.json").read_text())
    assert [s["pairs"] for s in session["steps"]] == [6, 8]
    assert len(session["pairs"]) == 8 and len(session["steps"][0]["next_pairs"]) == 2
    assert all(s["true_logcos"] > 0 and s["true_delta_e"] is None for s in session["steps"])
    assert len(in_plane_plan(out / "plan.csv")[0]) == 8
    for name in ("acquire.png", "measurement.csv", "model.onnx"):
        assert (out / name).stat().st_size > 0
    before = (out / "acquire.json").read_bytes()
    one_line_error(capsys, *args, expect="--overwrite")
    assert (out / "acquire.json").read_bytes() == before
    one_line_error(capsys, "acquire", "virtual:val-orange", "--start", "DS3", "--max", 8, "--out-dir", tmp_path / "s2",
                   expect="more than the budget")
    assert not (tmp_path / "s2").exists()


def test_the_pca_design_takes_each_pair_that_lowers_the_exact_posterior_variance_most():
    """The PCA fit is linear: its design's criterion is exact.  Each greedy step against an exhaustive
    search computed independently with direct inverses of the posterior precision."""
    from neuralbrdf.acquisition.design import DesignSettings, design_pca
    from neuralbrdf.evaluation.scores import hemisphere_pairs
    from neuralbrdf.geometry import inplane_to_vectors
    from neuralbrdf.models.pca_brdf import design_matrix, load_basis

    settings = DesignSettings(noise=0.01, normalise=True, blends=0, analytic=0, hemisphere_strata=(3, 4), seed=0)
    instrument = Instrument(60.0, 10.0, 0.0)
    plan = design_pca(3, instrument, settings)
    basis = load_basis().truncated(32)
    ridge = 0.003                                                       # configs/pca.yaml
    theta_i, theta_r = instrument.candidates()
    _, phi = design_matrix(basis, *inplane_to_vectors(theta_i, theta_r))
    _, hemisphere = design_matrix(basis, *hemisphere_pairs(0, (3, 4)))
    h = hemisphere.T @ hemisphere / len(hemisphere)
    precision = np.diag(1.0 / basis.scales ** 2)
    chosen = []
    for step in range(3):
        criteria = [np.inf if k in chosen else np.trace(h @ np.linalg.inv(precision + np.outer(row, row) / ridge))
                    for k, row in enumerate(phi)]                       # a pair is not chosen twice
        best = int(np.argmin(criteria))
        assert (plan.theta_i[step], plan.theta_r[step]) == (theta_i[best], theta_r[best])
        assert plan.predicted_error[step + 1] == pytest.approx(np.sqrt(criteria[best]), rel=1e-6)
        precision = precision + np.outer(phi[best], phi[best]) / ridge
        chosen.append(best)
    assert plan.predicted_error[0] == pytest.approx(np.sqrt(np.trace(h @ np.diag(basis.scales ** 2))), rel=1e-6)


def test_plan_design_for_the_pca_prior_writes_a_plan_a_pca_fit_reads(tmp_path, capsys):
    out = tmp_path / "plan.csv"
    assert run("plan", "design", "--kind", "pca", "--budget", 4, "--step", 10, "--out", out) == 0
    assert "designed for pca: 4 pairs" in capsys.readouterr().out
    theta_i, theta_r = in_plane_plan(out)
    assert len(theta_i) == 4 and Instrument(60.0, 10.0, 0.0).measurable(theta_i, theta_r).all()
    one_line_error(capsys, "plan", "design", "--budget", 3, "--kind", "mlp", "--out", out,
                   expect="nlb_spectral, abc, pca")


@pytest.mark.parametrize("kd, A, B, C, eta", [([0.1, 0.2, 0.3], [0.5, 0.4, 0.3], 200.0, 0.8, 1.5),
                                              ([0.0, 0.05, 0.3], [5.0, 4.0, 3.0], 0.02, 1e6, 7.0)])
def test_the_abc_jacobians_are_the_finite_differences_of_its_log_cosine_values(kd, A, B, C, eta):
    """Against central differences of ``ln(1 + f cos θi)`` computed by the physics module itself
    (not the linearisation's own values), on a broad lobe and on the Gaussian limit."""
    from neuralbrdf.acquisition.abc_linear import AbcLinearisation, theta_of
    from neuralbrdf.geometry import inplane_to_vectors
    from neuralbrdf.physics.abc import abc_brdf_by_sharpness

    wi, wo = (torch.as_tensor(v) for v in inplane_to_vectors(np.array([10.0, 30.0, 60.0, -20.0, 45.0, 70.0]),
                                                              np.array([10.0, 25.0, 0.0, 40.0, 44.0, -70.0])))
    theta = theta_of(kd, A, B, C, eta)

    def y(t):
        k = 3
        f = abc_brdf_by_sharpness(wi, wo, t[:k], torch.exp(t[k:2 * k]), np.exp(float(t[6])), np.expm1(float(t[7])),
                                  np.exp(float(t[8])))
        return torch.log1p(f * wi[:, 2:3])

    jacobians = AbcLinearisation(3).jacobians(theta, wi, wo)
    assert jacobians.shape == (6, 3, 9)
    for d in range(9):
        step = torch.zeros(9, dtype=torch.float64)
        step[d] = 1e-6
        torch.testing.assert_close(jacobians[..., d], (y(theta + step) - y(theta - step)) / 2e-6, rtol=1e-5, atol=1e-8)


def test_the_abc_design_materials_ship_and_a_damaged_file_is_named(tmp_path):
    from neuralbrdf.acquisition.abc_linear import design_thetas, parameter_covariance

    names, thetas = design_thetas()
    assert len(names) >= 40 and thetas.shape == (len(names), 9) and torch.isfinite(thetas).all()
    assert not any(name.split(":")[1] in {"brass", "nylon", "tungsten-carbide"} for name in names)  # test materials
    covariance = parameter_covariance(thetas)
    assert torch.linalg.eigvalsh(covariance).min() > 0
    bad = tmp_path / "materials.json"
    bad.write_text('{"materials": [{"name": "x", "kd": [0.1, 0.1]}]}')
    with pytest.raises(InputError, match="materials.json.*not a file of ABC design materials"):
        design_thetas(bad)


def test_the_abc_design_takes_each_pair_that_lowers_the_mean_criterion_most():
    """Each greedy step of the ABC design against an exhaustive search with direct inverses of the
    posterior precision, per design material, from the linearisation's Jacobians."""
    from neuralbrdf.acquisition.abc_linear import AbcLinearisation, design_thetas, parameter_covariance
    from neuralbrdf.acquisition.design import DesignSettings, design_abc
    from neuralbrdf.evaluation.scores import hemisphere_pairs
    from neuralbrdf.geometry import inplane_to_vectors

    settings = DesignSettings(noise=0.03, normalise=True, blends=0, analytic=0, hemisphere_strata=(3, 4), seed=0)
    instrument = Instrument(60.0, 15.0, 0.0)
    plan = design_abc(3, instrument, settings)
    _, thetas = design_thetas()
    prior = parameter_covariance(thetas).numpy()
    lin = AbcLinearisation(3)
    theta_i, theta_r = instrument.candidates()
    wi, wo = (torch.as_tensor(v) for v in inplane_to_vectors(theta_i, theta_r))
    hwi, hwo = (torch.as_tensor(v) for v in hemisphere_pairs(0, (3, 4)))
    per_material = []
    for theta in thetas:
        scale = np.maximum(lin.values(theta, hwi, hwo).numpy().mean(0), 1e-3)
        jh = (lin.jacobians(theta, hwi, hwo).numpy() / scale[None, :, None]).reshape(-1, 9)
        h = jh.T @ jh / len(jh)
        j = lin.jacobians(theta, wi, wo).numpy() / (0.03 * scale[None, :, None])
        per_material.append((h / np.trace(h @ prior), j))
    precisions = [np.linalg.inv(prior)] * len(thetas)
    chosen = []
    for step in range(3):
        criteria = [np.inf if c in chosen else np.mean([np.trace(h @ np.linalg.inv(p + j[c].T @ j[c]))
                                                        for (h, j), p in zip(per_material, precisions)])
                    for c in range(len(theta_i))]
        best = int(np.argmin(criteria))
        assert (plan.theta_i[step], plan.theta_r[step]) == (theta_i[best], theta_r[best])
        assert plan.predicted_error[step + 1] == pytest.approx(np.sqrt(criteria[best]), rel=1e-6)
        precisions = [p + j[best].T @ j[best] for (_, j), p in zip(per_material, precisions)]
        chosen.append(best)


def test_plan_design_for_abc_writes_a_plan_an_abc_fit_reads(tmp_path, capsys):
    import neuralbrdf as nb

    out = tmp_path / "plan.csv"
    assert run("plan", "design", "--kind", "abc", "--budget", 6, "--step", 10, "--out", out) == 0
    assert "designed for abc: 6 pairs" in capsys.readouterr().out
    theta_i, theta_r = in_plane_plan(out)
    assert len(theta_i) == 6 and Instrument(60.0, 10.0, 0.0).measurable(theta_i, theta_r).all()
    nb.sample("virtual:gold", out, tmp_path / "gold.csv")
    assert nb.fit("abc", nb.read(tmp_path / "gold.csv"), run_dir=tmp_path / "run").metrics["fit/abc/success"]


def _grey_table(path, pairs):
    """An RGB table of a grey Lambertian-like material at ``pairs`` (signed in-plane degrees): quick to fit."""
    rows = "".join(f"{ti},{tr},0.2,0.2,0.2\n" for ti, tr in pairs)
    path.write_text("theta_i_signed,theta_r_signed,R,G,B\n" + rows, encoding="utf-8")
    return path


def test_watching_a_table_answers_at_each_change_and_reports_a_damaged_file_without_stopping(tmp_path):
    """The instrument's software rewrites the table: each change gets an answer from the one loaded
    network; a change that leaves the file unreadable is reported and watched on."""
    import neuralbrdf as nb

    pairs = [(0.0, 10.0), (20.0, 20.0), (40.0, -30.0), (-50.0, 50.0), (30.0, 0.0), (60.0, 55.0)]
    table = _grey_table(tmp_path / "grey.csv", pairs[:4])
    answers, errors = [], []

    def answered(answer):
        answers.append(answer.measured)
        if len(answers) == 1:
            _grey_table(table, pairs)                                     # more pairs measured
        else:
            table.write_text("theta_i_signed,theta_r_signed\n10,")      # caught half-written

    reads = nb.watch_next_pairs(table, 2, tmp_path / "next.csv", step=10.0, poll_s=0.01, reads=3,
                                on_answer=answered, on_error=errors.append)
    assert reads == 3 and answers == [4, 6] and len(errors) == 1
    assert str(table) in str(errors[0])
    assert len(in_plane_plan(tmp_path / "next.csv")[0]) == 2
    with pytest.raises(InputError, match="missing.csv: no such file to watch"):
        nb.watch_next_pairs(tmp_path / "missing.csv", reads=1)


def test_plan_next_watch_prints_each_answer_and_stops_on_ctrl_c(tmp_path, capsys, monkeypatch):
    import time

    table = _grey_table(tmp_path / "grey.csv", [(0.0, 10.0), (20.0, 20.0), (40.0, -30.0)])

    def interrupt(seconds):                                   # nothing changed after the first answer: Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(time, "sleep", interrupt)
    assert run("plan", "next", table, "--count", 1, "--step", 10, "--watch", "--out", tmp_path / "next.csv") == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"watching {table}") and out[-1] == "stopped" and len(out) == 3
    assert "3 pairs measured; the fit's error now" in out[1] and out[1][2] == ":" == out[1][5]   # HH:MM:SS first
    assert len(in_plane_plan(tmp_path / "next.csv")[0]) == 1
