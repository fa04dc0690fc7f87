"""Unit slips (neuralbrdf.data.units): a table whose numbers betray radians, µm, Å, percent or a
cosine weight is refused wherever it is read — a file, ``nb.read``, ``nb.fit``, a fit's
``data.path`` or ``data.sources``, ``to-rgb``, ``plot``, ``calibrate``, a study profile — in one
line naming the file and that door's override, before any run folder is left; and the project's
own data (virtual materials, DS1–DS4, the Löw et al. set, NBRDF proxies, a MERL file) pass."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

import neuralbrdf as nb
from neuralbrdf.cli.main import main as cli
from neuralbrdf.data.gcms import read_gcms, write_gcms
from neuralbrdf.data.inplane_table import write_inplane_table
from neuralbrdf.data.plans import PLAN_NAMES
from neuralbrdf.data.table import BrdfTable, write_table
from neuralbrdf.data.units import UnitsError, check_units, unit_problem
from neuralbrdf.errors import InputError
from neuralbrdf.lightning.run import main as train
from neuralbrdf.sources import sample_file, virtual_measurement, virtual_truth
from neuralbrdf.virtual.instrument import default_data_path

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
REPORT_PROXIES = ("tungsten-carbide", "nylon", "brass", "blue-acrylic", "specular-black-phenolic")
QUICK_ABC = ["--model.n_starts", "1", "--data.eval_plan", "null", "--trainer.enable_progress_bar", "false"]


@pytest.fixture(scope="module")
def gold():
    """The virtual gold measured on DS1 (spectral, 1001 rows, sr^-1)."""
    return virtual_measurement("gold", "DS1", 0.0, 0, 1)


def _with(table: BrdfTable, **changes) -> BrdfTable:
    return dataclasses.replace(table, **changes)


def _cos(degrees):
    return np.cos(np.radians(degrees))[:, None]


#: Each slip: how a correct table becomes a wrong one, and the words that name it.
SLIPS = {
    "radians": (lambda t: _with(t, theta_i=np.radians(t.theta_i), theta_o=np.radians(t.theta_o)),
                "angles look like radians"),
    "azimuth radians": (lambda t: _with(t, phi_i=np.radians(t.phi_i), phi_o=np.radians(t.phi_o)),
                        "azimuths look like radians"),
    "micrometres": (lambda t: _with(t, wavelengths=t.wavelengths / 1000), "wavelengths look like micrometres"),
    "angstroms": (lambda t: _with(t, wavelengths=t.wavelengths * 10), "wavelengths look like angstroms"),
    "percent reflectance factor": (lambda t: _with(t, values=t.values * 100 * math.pi), "look like percent"),
    "BRDF x cos theta_o": (lambda t: _with(t, values=t.values * _cos(t.theta_o)), "BRDF x cos theta_o"),
    "BRDF x cos theta_i": (lambda t: _with(t, values=t.values * _cos(t.theta_i)), "BRDF x cos theta_i"),
}


@pytest.mark.parametrize("slip", SLIPS)
def test_each_slip_is_refused_from_a_file_naming_it_and_the_override(gold, tmp_path, slip):
    wrong, words = SLIPS[slip]
    path = tmp_path / "gold.csv"
    write_table(wrong(gold), path)
    with pytest.raises(UnitsError) as caught:
        nb.read(path)
    message = str(caught.value)
    assert message.startswith(str(path)) and words in message and "trust_units=True" in message
    assert "\n" not in message
    assert nb.read(path, trust_units=True).samples.n_rows == gold.n_rows  # the override reads it as it is


def test_signed_in_plane_tables_are_checked_too(gold, tmp_path):
    path = tmp_path / "gold_signed.csv"
    write_inplane_table(SLIPS["radians"][0](gold), path)
    with pytest.raises(UnitsError, match="angles look like radians"):
        nb.read(path)


def test_a_calibrated_gcms_file_is_checked_and_calibrate_refuses_it(tmp_path, capsys):
    """Radian angles in a GCMS raw file survive calibration as radians: refused by nb.read and by
    ``neuralbrdf calibrate`` (its own flag names the override)."""
    sample, reference = (read_gcms(default_data_path(name)) for name in ("gold", "munsell_n9"))
    for measurement, name in ((sample, "gold.csv"), (reference, "n9.csv")):
        write_gcms(dataclasses.replace(measurement, theta_i=np.radians(measurement.theta_i),
                                       theta_r=np.radians(measurement.theta_r), lines=None), tmp_path / name)
    with pytest.raises(UnitsError, match="angles look like radians"):
        nb.read(tmp_path / "gold.csv", tmp_path / "n9.csv")
    out = tmp_path / "table.csv"
    assert cli(["calibrate", str(tmp_path / "gold.csv"), "--reference", str(tmp_path / "n9.csv"), "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert "angles look like radians" in error and "--trust-units" in error and not out.exists()
    assert cli(["calibrate", str(tmp_path / "gold.csv"), "--reference", str(tmp_path / "n9.csv"), "--out", str(out),
                "--trust-units"]) == 0


@pytest.mark.parametrize("command", ["to-rgb", "plot"])
def test_table_commands_refuse_a_slip_and_take_trust_units(gold, tmp_path, capsys, command):
    path, out = tmp_path / "gold.csv", tmp_path / ("out.csv" if command == "to-rgb" else "out.png")
    write_table(SLIPS["percent reflectance factor"][0](gold), path)
    assert cli([command, str(path), "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0 and str(path) in error and "look like percent" in error and "--trust-units" in error
    assert not out.exists()
    assert cli([command, str(path), "--out", str(out), "--trust-units"]) == 0 and out.is_file()


def test_a_fit_refuses_a_slip_with_exit_2_and_leaves_no_run_folder(gold, tmp_path, capsys, monkeypatch):
    """``train fit`` on a radian table: one line naming the file and --data.trust_units, status 2,
    no run folder (neither the one asked for nor a default one), and an existing run untouched."""
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "gold_rad.csv"
    write_table(SLIPS["radians"][0](gold), path)
    assert train(["fit", "--config", "abc", "--data.path", str(path), "--run_dir", "asked", *QUICK_ABC]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert str(path) in error and "angles look like radians" in error
    assert "--data.trust_units true" in error
    assert train(["fit", "--config", "abc", "--data.path", str(path), *QUICK_ABC]) == 2
    assert not (tmp_path / "asked").exists() and not (tmp_path / "runs").exists()
    assert train(["fit", "--config", "abc", "--run_dir", "old", *QUICK_ABC]) == 0
    before = sorted(p.name for p in (tmp_path / "old").rglob("*"))
    assert train(["fit", "--config", "abc", "--data.path", str(path), "--run_dir", "old", "--overwrite", *QUICK_ABC]) == 2
    assert sorted(p.name for p in (tmp_path / "old").rglob("*")) == before


def test_a_spectral_fit_refuses_micrometres(gold, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "gold_um.csv"
    write_table(SLIPS["micrometres"][0](gold), path)
    assert train(["fit", "--config", "spectral_mlp", "--data.path", str(path), "--run_dir", "run"]) == 2
    assert "wavelengths look like micrometres" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_latent_fit_sources_name_their_own_override(gold, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "gold_rad.csv"
    write_table(SLIPS["radians"][0](gold), path)
    sources = f'[{{"virtual": "cyan"}}, {{"path": "{path}"}}]'
    assert train(["fit", "--config", "nlb_spectral", "--data.sources", sources, "--run_dir", "run"]) == 2
    assert "trust_units: true in data.sources[1]" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
    assert train(["fit", "--config", "nlb_spectral", "--data.sources", '[{"virtual": "cyan", "trust_units": true}]',
                  "--run_dir", "run"]) == 2
    assert "'trust_units' is true or false, for a 'path'" in capsys.readouterr().err
    from neuralbrdf.lightning.latent_fit_data import LatentFitData

    data = LatentFitData(sources=[{"virtual": "cyan"}, {"path": str(path), "trust_units": True}], eval_plan=None,
                         spectral=None)
    data.setup()  # the source's own trust_units reads it as it is
    assert data.material_names == ["cyan", "gold_rad"]


def test_the_python_fit_names_the_python_override_and_trust_units_reaches_the_fit(gold, tmp_path):
    path = tmp_path / "gold_rad.csv"
    write_table(SLIPS["radians"][0](gold), path)
    quick = {"model.n_starts": 1, "data.eval_plan": None}
    with pytest.raises(UnitsError, match=r"nb.read\(..., trust_units=True\)"):
        nb.fit("abc", path, run_dir=tmp_path / "run", overrides=quick)
    assert not (tmp_path / "run").exists()
    source = nb.read(path, trust_units=True)
    assert source.options() == {"path": str(path), "trust_units": True}
    result = nb.fit("abc", source, run_dir=tmp_path / "run", overrides=quick)  # the fit reads it as it is too
    assert result.checkpoint.is_file()


def test_a_study_profile_refuses_a_slipped_table_at_load(gold, tmp_path):
    from neuralbrdf.study.profile import load_profile

    path = tmp_path / "gold_rad.csv"
    write_table(SLIPS["radians"][0](gold), path)
    profile = tmp_path / "p.yaml"
    text = ("render: {spp: 1, resolution: 16}\ncost: {spp: 1, resolution: 16, repeats: 1, batch: 1024}\n"
            "materials:\n  - {name: mine, truth: virtual:gold, table: gold_rad.csv%s}\n"
            "variants:\n  - {name: abc, method: abc, config: configs/abc.yaml}\n")
    profile.write_text(text % "")
    with pytest.raises(InputError, match=r"materials\[0\].table.*angles look like radians.*trust_units: true in materials\[0\]"):
        load_profile(profile)
    profile.write_text(text % ", trust_units: true")
    assert load_profile(profile).materials[0].trust_units


# --------------------------------------------------------------------------- no false alarms


def test_the_virtual_materials_pass_on_every_plan_with_instrument_noise():
    for material in ("cyan", "magenta", "gold", "gonio", "munsell_n9"):
        for plan in ("DS1", "DS2", "DS3", "DS4"):
            assert unit_problem(virtual_truth(material, plan)) is None, (material, plan)
            for noise, seed in ((0.01, 0), (0.1, 1), (0.2, 2)):
                assert unit_problem(virtual_measurement(material, plan, noise, seed, seed + 1)) is None, (material, plan, noise)
    assert unit_problem(virtual_truth("munsell_n9", "low")) is None  # the brightest, on the Löw et al. set
    for name in ("cyan", "magenta", "gold", "gonio"):  # the shipped measurements, as every fit reads them
        nb.read(f"virtual:{name}")


def test_a_merl_file_sampled_on_every_plan_passes(tmp_path):
    from neuralbrdf.data.merl_binary import MERL_SHAPE, MerlBrdf, sample_merl, write_merl

    n_h = MERL_SHAPE[0]
    theta_h = ((np.arange(n_h) + 0.5) ** 2 / 90.0)[:, None, None]
    albedo = np.array([0.2, 0.5, 0.9])[:, None, None, None]
    values = np.broadcast_to(albedo / math.pi + 3.0 * np.cos(np.radians(theta_h)) ** 40, (3, *MERL_SHAPE)).copy()
    write_merl(values, tmp_path / "m.binary")
    brdf = MerlBrdf.load(tmp_path / "m.binary")
    for plan in PLAN_NAMES:
        assert unit_problem(sample_merl(brdf, plan)) is None, plan


@pytest.mark.skipif(not (SHARED / "merl-nbrdf").is_dir(), reason=f"NBRDF proxies not found at {SHARED}")
def test_the_report_proxies_pass_on_the_in_plane_plans():
    for name in REPORT_PROXIES:
        for plan in ("DS1", "DS2", "DS3", "DS4"):
            assert unit_problem(sample_file(SHARED / "merl-nbrdf" / f"{name}.h5", plan)) is None, (name, plan)


@pytest.mark.slow
@pytest.mark.skipif(not (SHARED / "merl-nbrdf").is_dir(), reason=f"NBRDF proxies not found at {SHARED}")
def test_every_proxy_and_virtual_material_passes_on_every_plan():
    for path in sorted(SHARED.glob("*-nbrdf/*.h5")):
        for plan in PLAN_NAMES:
            assert unit_problem(sample_file(path, plan)) is None, (path.name, plan)
    for material in ("cyan", "magenta", "gold", "gonio"):
        assert unit_problem(virtual_truth(material, "low")) is None, material


def test_trust_units_skips_the_checks(gold):
    wrong = SLIPS["radians"][0](gold)
    with pytest.raises(UnitsError):
        check_units(wrong)
    assert check_units(wrong, trust_units=True) is wrong


def test_few_rows_are_not_judged_by_their_angles(gold):
    """Fewer than a handful of rows may all lie near the normal: no radians finding."""
    rows = slice(0, 5)
    few = BrdfTable(np.full(5, 1.0), np.zeros(5), np.linspace(0.2, 1.2, 5), np.zeros(5), gold.values[rows],
                    gold.wavelengths)
    assert unit_problem(few) is None


def test_polar_angles_above_90_are_refused_with_the_convention_named(tmp_path):
    """A scattering angle of 0-180° (or a signed angle) in a spherical table: the reader's range
    check names the line and column, and says how angles are measured and where signed ones go."""
    path = tmp_path / "t.csv"
    path.write_text("theta_i,phi_i,theta_o,phi_o,R,G,B\n30,0,120,0,1,1,1\n")
    with pytest.raises(InputError) as caught:
        nb.read(path)
    assert str(caught.value) == (f"{path}, line 2, column 'theta_o': angle 120° outside [0, 90] degrees (polar angles "
                                 "are measured from the normal; signed in-plane angles go in an in-plane table: "
                                 "theta_i_signed, theta_r_signed)")
