"""RGL ``.bsdf`` measurements (Dupuy & Jakob 2018): files written by the tests with a closed form
(:mod:`rgl_fixtures`), RGB and spectral, and the shared real file; read, sampled, exported as a
truth and evaluated against, every step checked against the closed form or Mitsuba's own
``measured`` plugin, and every bad file refused in one line before Mitsuba sees it."""

import struct
from pathlib import Path

import numpy as np
import pytest

from neuralbrdf.cli.main import main as cli
from neuralbrdf.data.calibration import CALIBRATED_WAVELENGTHS_NM
from neuralbrdf.data.rgl_bsdf import RglBsdf, mitsuba_variant, sample_rgl
from neuralbrdf.data.table import read_table
from neuralbrdf.data.tensor_file import read_tensor_file, write_tensor_file
from neuralbrdf.errors import InputError
from neuralbrdf.geometry import spherical_pair_to_vectors, spherical_to_vector
from rgl_fixtures import closed_form, write_closed_form

SHARED_FILE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "rgl-bsdf" / "acrylic_felt_green_rgb.bsdf"
needs_shared = pytest.mark.skipif(not SHARED_FILE.is_file(), reason="../shared/data/rgl-bsdf is absent")
NEGATIVE_RED = 0.4


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rgl")
    paths = {"rgb": folder / "closed_rgb.bsdf", "spectral": folder / "closed_spec.bsdf",
             "negative": folder / "negative_rgb.bsdf"}
    write_closed_form(paths["rgb"], spectral=False)
    write_closed_form(paths["spectral"], spectral=True)
    write_closed_form(paths["negative"], spectral=False, negative_red=NEGATIVE_RED)
    return paths


@pytest.fixture(scope="module")
def resampled(files):
    """The RGB file's resampled truth, a model close to the measurement."""
    import neuralbrdf as nb

    return nb.truth(files["rgb"], files["rgb"].with_name("resampled.onnx"))


def _pairs(n=4000, max_theta=85.0, seed=0):
    rng = np.random.default_rng(seed)
    wi = spherical_to_vector(rng.uniform(0.0, max_theta, n), rng.uniform(0.0, 360.0, n))
    wo = spherical_to_vector(rng.uniform(0.0, max_theta, n), rng.uniform(0.0, 360.0, n))
    return wi, wo


def _plugin_eval(path, wi, wo, variant="llvm_ad_rgb", wavelength=None):
    """Mitsuba's ``measured`` plugin called directly, ``si.wi = wi``: ``eval`` (``f cos θo``)."""
    import drjit as dr

    with mitsuba_variant(variant) as mi:
        bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
        si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
        si.wi = mi.Vector3f(*(mi.Float(wi[:, k].astype(np.float32)) for k in range(3)))
        if wavelength is not None:
            si.wavelengths = mi.Spectrum(*([dr.opaque(mi.Float, float(wavelength))] * dr.size_v(mi.Spectrum)))
        value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*(mi.Float(wo[:, k].astype(np.float32)) for k in range(3))))
        return np.asarray(value, dtype=np.float64).T


# --------------------------------------------------------------------------- the container


def test_tensor_file_round_trips_every_dtype(tmp_path):
    fields = {name: (np.arange(24).reshape(2, 3, 4) % 7).astype(dtype)
              for name, dtype in (("a", "u1"), ("b", "<i2"), ("c", "<u4"), ("d", "<i8"), ("e", "<f2"), ("f", "<f4"),
                                  ("g", "<f8"))}
    fields["scalar_list"] = np.array([3.5], dtype="<f4")
    write_tensor_file(tmp_path / "t.bsdf", fields)
    read = read_tensor_file(tmp_path / "t.bsdf")
    assert list(read) == list(fields)
    for name, array in fields.items():
        assert read[name].dtype == array.dtype and np.array_equal(read[name], array)


@needs_shared
def test_the_real_file_parses_and_writes_back_byte_for_byte(tmp_path):
    fields = read_tensor_file(SHARED_FILE)
    write_tensor_file(tmp_path / "copy.bsdf", fields)
    assert (tmp_path / "copy.bsdf").read_bytes() == SHARED_FILE.read_bytes()
    brdf = RglBsdf.load(SHARED_FILE)
    assert brdf.description == "Green acrylic felt (Edukit A4)" and not brdf.is_spectral and brdf.negative is None
    # eight incident angles from normal to grazing, one azimuth: isotropic
    assert len(brdf.theta_i_deg) == 8 and brdf.theta_i_deg[0] == 0.0 and brdf.theta_i_deg[-1] == pytest.approx(90.0)
    assert np.all(np.diff(brdf.theta_i_deg) > 0) and fields["phi_i"].shape == (1,)
    # 'valid' is one bit per cell of the 8 x 32 x 32 grids; most cells were seen by the instrument
    bits = np.unpackbits(fields["valid"]).reshape(8, 32, 32)
    assert 0.8 < bits.mean() < 0.95 and np.all(bits.reshape(8, -1).mean(axis=1) >= 0.8)


# --------------------------------------------------------------------------- conventions


@pytest.mark.parametrize("kind", ["rgb", "spectral"])
def test_values_are_the_closed_form_with_wi_the_light(files, kind):
    """The file's theta_i is the light; f = eval / cos θo.  The closed form grows fivefold with θi, so
    exchanging wi and wo (or dividing by the other cosine) misses it by far more than the tolerance."""
    spectral = kind == "spectral"
    brdf = RglBsdf.load(files[kind])
    wi, wo = _pairs()
    bands = np.array([400.0, 455.0, 550.0, 700.0])
    got = brdf.evaluate(wi, wo, bands if spectral else None)
    expected = closed_form(wi, wo, spectral, bands)
    np.testing.assert_allclose(got, expected, rtol=2e-5)
    swapped = closed_form(wo, wi, spectral, bands)
    assert np.median(np.abs(got - swapped) / swapped) > 0.1
    other_cosine = expected * (wo[:, 2] / wi[:, 2])[:, None]
    assert np.median(np.abs(got - other_cosine) / other_cosine) > 0.2


@needs_shared
def test_the_real_file_is_read_with_the_light_as_the_plugins_si_wi_at_grazing_pairs():
    """At grazing incidence the real measurement is not reciprocal: exchanging wi and wo changes it by
    5-38 %, far above the float32 agreement asserted, so a swap in the reader would fail here."""
    theta_i, theta_o = np.array([80.0, 85.0, 75.0, 70.0, 80.0]), np.array([10.0, 20.0, 0.0, 5.0, 40.0])
    wi, wo = spherical_pair_to_vectors(theta_i, np.zeros(5), theta_o, np.array([180.0, 180.0, 0.0, 90.0, 0.0]))
    brdf = RglBsdf.load(SHARED_FILE)
    got = brdf.evaluate(wi, wo)
    np.testing.assert_allclose(got, _plugin_eval(SHARED_FILE, wi, wo) / wo[:, 2:3], rtol=1e-6)
    swapped = brdf.evaluate(wo, wi)
    assert np.max(np.abs(got - swapped) / swapped) > 0.3 and np.min(np.abs(got - swapped).max(axis=1) / got.max(axis=1)) > 0.02


def test_the_spectral_file_in_mitsubas_spectral_variant_is_the_closed_form(files):
    wi, wo = _pairs(200)
    for nm in (400.0, 517.0, 700.0):
        plugin = _plugin_eval(files["spectral"], wi, wo, "llvm_ad_spectral", nm)[:, 0] / wo[:, 2]
        np.testing.assert_allclose(plugin, closed_form(wi, wo, True, [nm])[:, 0], rtol=2e-5)


# --------------------------------------------------------------------------- sample, read, negative values


@pytest.mark.parametrize("kind", ["rgb", "spectral"])
def test_sample_writes_the_plugins_values_at_the_plans_pairs(files, kind, tmp_path, capsys):
    out = tmp_path / "t.csv"
    assert cli(["sample", str(files[kind]), "--plan", "DS2", "--out", str(out)]) == 0
    table = read_table(out)
    assert table.n_rows == 185
    wi, wo = table.vectors()
    spectral = kind == "spectral"
    if spectral:  # the report's bands, 400-700 nm every 10 nm
        np.testing.assert_array_equal(table.wavelengths, CALIBRATED_WAVELENGTHS_NM)
        columns = [0, 11, 22, 30]  # 400, 510, 620 and 700 nm
        plugin = np.stack([_plugin_eval(files[kind], wi, wo, "llvm_ad_spectral", CALIBRATED_WAVELENGTHS_NM[k])[:, 0]
                           for k in columns], axis=1) / wo[:, 2:3]
        values = table.values[:, columns]
    else:
        assert table.wavelengths is None
        plugin, values = _plugin_eval(files[kind], wi, wo) / wo[:, 2:3], table.values
    above = plugin > 1e-3
    assert np.median(np.abs(values[above] - plugin[above]) / plugin[above]) < 1e-5
    bands = CALIBRATED_WAVELENGTHS_NM[columns] if spectral else None
    np.testing.assert_allclose(values, closed_form(wi, wo, spectral, bands), rtol=1e-4)


def test_negative_values_are_clipped_to_zero_with_one_warning(files, tmp_path, capsys):
    with pytest.warns(UserWarning, match=r"(\d+) of (\d+) stored rgb values \((\d+\.\d)%\) are negative .*most "
                                         r"negative -\d[.\d]*\);.*clipped to 0") as record:
        brdf = RglBsdf.load(files["negative"])
    stored = read_tensor_file(files["negative"])["rgb"]
    assert brdf.negative.count == int((stored < 0).sum()) > 0 and brdf.negative.most_negative == float(stored.min())
    assert len(record) == 1
    wi, wo = _pairs(2000)
    expected = closed_form(wi, wo, False, negative_red=NEGATIVE_RED)
    assert (expected[:, 0] < 0).mean() > 0.3  # the red channel is out of gamut at many pairs
    np.testing.assert_allclose(brdf.evaluate(wi, wo), np.clip(expected, 0.0, None), rtol=2e-5, atol=1e-7)
    # the same policy and the same line from sample, read and export-truth
    lines = []
    for args in (["sample", str(files["negative"]), "--plan", "DS3", "--out", str(tmp_path / "t.csv")],
                 ["export-truth", str(files["negative"]), "--out", str(tmp_path / "t.onnx")]):
        assert cli(args) == 0
        err = capsys.readouterr().err
        lines += [line for line in err.splitlines() if "negative" in line]
    import neuralbrdf as nb

    with pytest.warns(UserWarning, match="clipped to 0") as record:
        source = nb.read(files["negative"], plan="DS3")
    assert source.samples.values.min() >= 0.0 and (source.samples.values[:, 0] == 0).any()
    assert len(lines) == 2 and lines[0] == lines[1] and lines[0] == f"warning: {record[0].message}"


# --------------------------------------------------------------------------- bad files


def _bad_files(good: Path, folder: Path) -> dict[str, Path]:
    data = good.read_bytes()
    fields = {name: np.array(value) for name, value in read_tensor_file(good).items()}
    bad = {}

    def written(name, raw=None, **changed):
        path = folder / f"{name}.bsdf"
        if raw is not None:
            path.write_bytes(raw)
        else:
            write_tensor_file(path, {**fields, **changed})
        bad[name] = path

    written("truncated", data[: len(data) // 2])
    written("header_cut", data[:30])
    written("wrong_magic", b"tensor_fild\0" + data[12:])
    written("wrong_version", data[:12] + bytes([2, 0]) + data[14:])
    written("unknown_dtype", data[:14] + struct.pack("<I", 1) + struct.pack("<H", 1) + b"x" + struct.pack("<HBQ", 1, 42, 64)
            + struct.pack("<Q", 1) + b"\0" * 64)
    stacked = {name: np.concatenate([fields[name]] * 2) for name in ("vndf", "luminance", "rgb")}
    written("anisotropic", phi_i=np.array([0.0, np.pi], dtype="<f4"), **stacked)
    nan = fields["rgb"].copy()
    nan[0, 3, 1, 5, 7] = np.nan
    written("nan_value", rgb=nan)
    write_tensor_file(folder / "missing_field.bsdf", {k: v for k, v in fields.items() if k != "luminance"})
    bad["missing_field"] = folder / "missing_field.bsdf"
    written("wrong_shape", luminance=fields["luminance"][:, :3])
    narrow = folder / "narrow_spec.bsdf"
    spectral = {name: np.array(value) for name, value in read_tensor_file(good.with_name("closed_spec.bsdf")).items()}
    write_tensor_file(narrow, {**spectral, "wavelengths": np.linspace(450.0, 800.0, len(spectral["wavelengths"]),
                                                                       dtype="<f4")})
    bad["narrow_spectral"] = narrow
    folder.joinpath("a_directory.bsdf").mkdir()
    bad["directory"] = folder / "a_directory.bsdf"
    return bad


EXPECTED_REASON = {
    "truncated": "truncated", "header_cut": "truncated tensor_file: the header ends", "wrong_magic": "not a Mitsuba "
    "tensor_file", "wrong_version": "version 2.0; expected 1.0", "unknown_dtype": "type code 42",
    "anisotropic": "anisotropic", "nan_value": "field 'rgb': non-finite value nan at index [0, 3, 1, 5, 7]",
    "missing_field": "missing field(s) luminance", "wrong_shape": "field 'luminance': expected shape",
    "narrow_spectral": "covers 450-800 nm", "directory": "is a directory",
}


#: Each door a measurement file comes in by: (the arguments reading ``{bad}`` and writing ``{out}``,
#: the output's suffix); evaluate scores a model file against it, train fit reads it as a source.
DOORS = {
    "sample": (["sample", "{bad}", "--plan", "DS3", "--out", "{out}"], ".csv"),
    "export-truth": (["export-truth", "{bad}", "--out", "{out}"], ".onnx"),
    "evaluate": (["evaluate", "{model}", "--truth", "{bad}", "--out-dir", "{out}", "--no-render"], ""),
    "train": (["train", "fit", "--config", "abc", "--data.rgl", "{bad}", "--run_dir", "{out}"], ""),
}


@pytest.mark.parametrize("command", DOORS)
def test_every_bad_file_is_one_line_naming_it_exit_2_and_nothing_written(files, resampled, tmp_path, capsys, command):
    bad = _bad_files(files["rgb"], tmp_path)
    assert set(bad) == set(EXPECTED_REASON)
    arguments, suffix = DOORS[command]
    for name, path in bad.items():
        out = tmp_path / f"{name}_out{suffix}"
        assert cli([a.format(bad=path, out=out, model=resampled.path) for a in arguments]) == 2, name
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(path) in err[0] and EXPECTED_REASON[name] in err[0], (name, err)
        assert err[0].startswith(f"neuralbrdf {command}: error: ") and not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.endswith("_out") or p.suffix in (".csv", ".onnx")]


def _hostile_header(fields: list[tuple[bytes, int, int, list[int]]], size: int) -> bytes:
    """A tensor_file of ``size`` bytes whose header lists ``(name, rank, type code, shape)``."""
    table = b"".join(struct.pack(f"<H{len(name)}sHBQ{len(shape)}Q", len(name), name, rank, code, 0, *shape)
                     for name, rank, code, shape in fields)
    head = b"tensor_file\0" + bytes([1, 0]) + struct.pack("<I", len(fields)) + table
    return head + b"\0" * max(0, size - len(head))


def test_header_quantities_a_real_file_never_has_are_one_short_line_from_a_real_process(tmp_path):
    """An absurd rank (a NumPy traceback before), a field count the file cannot hold, a long name
    and a shape far beyond the file: one short line naming the file and the item, exit 2."""
    import subprocess
    import sys
    import time

    cases = {
        "rank": (_hostile_header([(b"rgb", 40, 10, [1] * 40)], 4096), "field 'rgb' has rank 40; at most 16"),
        "count": (b"tensor_file\0" + bytes([1, 0]) + struct.pack("<I", 4_000_000) + b"\0" * 100,
                  "claims 4000000 fields; at most 1024"),
        "name": (_hostile_header([(b"n" * 5000, 1, 10, [1])], 8192), "field 1 of 1 has a name of 5000 bytes"),
        "shape": (_hostile_header([(b"rgb", 5, 10, [2**40] * 5)], 4096), "claims a dimension of 1099511627776"),
        "zero_shape": (_hostile_header([(b"rgb", 2, 10, [0, 2**63])], 4096), "claims a dimension of"),
    }
    for name, (raw, reason) in cases.items():
        path = tmp_path / f"{name}.bsdf"
        path.write_bytes(raw)
        start = time.monotonic()
        run = subprocess.run([sys.executable, "-m", "neuralbrdf", "sample", str(path), "--plan", "DS3", "--out",
                              str(tmp_path / f"{name}.csv")], capture_output=True, text=True, timeout=120)
        err = run.stderr.strip().splitlines()
        assert run.returncode == 2 and len(err) == 1 and str(path) in err[0] and reason in err[0], (name, run.stderr)
        assert len(err[0]) < 300 + len(str(path)) and time.monotonic() - start < 60
        assert not (tmp_path / f"{name}.csv").exists()


def test_many_tiny_fields_are_refused_in_one_short_line_without_a_dump(tmp_path):
    """1 024 valid empty fields (the most read) and no RGL field among them: the line names a few
    and counts the rest; a million such fields are refused before any is read."""
    import time
    import tracemalloc

    many = tmp_path / "many.bsdf"
    many.write_bytes(_hostile_header([(f"f{i:05d}".encode(), 1, 1, [0]) for i in range(1024)], 0))
    with pytest.raises(InputError) as caught:
        RglBsdf.load(many)
    assert "missing field(s) description" in str(caught.value) and "and 1012 more" in str(caught.value)
    assert len(str(caught.value)) < 600
    million = tmp_path / "million.bsdf"
    million.write_bytes(_hostile_header([(b"f", 1, 1, [0])] * 1_000_000, 0))
    tracemalloc.start()
    start = time.monotonic()
    with pytest.raises(InputError, match="claims 1000000 fields; at most 1024"):
        read_tensor_file(million)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert time.monotonic() - start < 5 and peak < 2 * million.stat().st_size


def _mutations(data: bytes, rng: np.random.Generator, n: int):
    """``n`` hostile variants of a tensor_file: random bytes of the header, random u64 and u16
    words there (ranks, offsets, shapes), cuts, and random bytes of the data (NaNs, negatives)."""
    header_end = 400
    for index in range(n):
        raw = bytearray(data)
        kind = index % 4
        if kind == 0:
            for _ in range(rng.integers(1, 6)):
                raw[rng.integers(12, header_end)] = int(rng.integers(0, 256))
        elif kind == 1:
            at = int(rng.integers(16, header_end - 8))
            width = 8 if rng.random() < 0.5 else 2
            value = int(rng.choice([0, 1, 2**15, 2**16 - 1, 2**31, 2**63, 2**64 - 1, int(rng.integers(0, 2**32))]))
            raw[at:at + width] = (value % 2**(8 * width)).to_bytes(width, "little")
        elif kind == 2:
            raw = raw[: int(rng.integers(0, len(raw)))]
        else:
            for _ in range(rng.integers(1, 50)):
                at = int(rng.integers(header_end, len(raw) - 4))
                raw[at:at + 4] = rng.choice([np.float32("nan"), np.float32(-1.0), np.float32("inf")]).tobytes()
        yield bytes(raw)


@needs_shared
def test_fuzzed_real_file_is_a_valid_read_or_one_line_in_bounded_time_and_memory(tmp_path):
    import time
    import tracemalloc
    import warnings

    data = SHARED_FILE.read_bytes()
    path = tmp_path / "fuzzed.bsdf"
    outcomes = {"read": 0, "refused": 0}
    tracemalloc.start()
    for raw in _mutations(data, np.random.default_rng(45), 400):
        path.write_bytes(raw)
        start = time.monotonic()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                RglBsdf.load(path)
            outcomes["read"] += 1
        except InputError as error:
            line = str(error)
            assert "\n" not in line and line.startswith(str(path)) and len(line) < 400 + len(str(path)), line
            outcomes["refused"] += 1
        assert time.monotonic() - start < 5
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert outcomes["read"] > 0 and outcomes["refused"] > 100, outcomes
    assert peak < 10 * len(data)


# --------------------------------------------------------------------------- sources


def test_an_rgl_file_is_a_source_everywhere_a_merl_file_is(files, tmp_path):
    import neuralbrdf as nb
    from neuralbrdf.sources import check_source, load_material, source_name

    source = nb.read(files["spectral"], plan="DS3")
    assert (source.kind, source.name, source.is_spectral, source.has_truth) == ("rgl", "closed_spec", True, True)
    assert source.options() == {"rgl": str(files["spectral"]), "plan": "DS3"} and source.samples.n_rows == 57
    material = load_material(rgl=str(files["rgb"]), plan="DS2", eval_plan="DS1")
    assert material.name == "closed_rgb" and material.fit.n_rows == 185 and material.truth.n_rows == 1001
    entry = check_source({"rgl": str(files["rgb"]), "plan": "DS4"}, "data.sources[0]")
    assert source_name(entry) == "closed_rgb"
    with pytest.raises(InputError, match="plan 'DS9'|'plan' is for nbrdf, merl and rgl"):
        check_source({"rgl": str(files["rgb"]), "plan": "DS9"}, "data.sources[0]")
    table = sample_rgl(RglBsdf.load(files["spectral"]), "DS4")
    assert table.n_rows == 6 and table.wavelengths.tolist() == CALIBRATED_WAVELENGTHS_NM.tolist()


def test_the_fit_data_modules_take_an_rgl_source(files):
    from neuralbrdf.lightning.latent_fit_data import LatentFitData
    from neuralbrdf.lightning.material_data import SingleMaterialData

    single = SingleMaterialData(rgl=str(files["spectral"]), plan="DS3", eval_plan=None)
    single.setup()
    assert single.material.fit.is_spectral and single.material.fit.n_rows == 57
    latent = LatentFitData(sources=[{"rgl": str(files["spectral"])}, {"rgl": str(files["rgb"]), "plan": "DS4"}],
                           plan="DS3", eval_plan=None)
    latent.setup()
    assert latent.material_names == ["closed_spec", "closed_rgb"] and latent.spectral is False


# --------------------------------------------------------------------------- as a truth


def _logcos(model_values, truth_values, wi):
    from neuralbrdf.metrics import hemisphere_logcos_rmse

    return hemisphere_logcos_rmse(np.clip(model_values, 0, None), truth_values, np.degrees(np.arccos(wi[:, 2])))


def test_export_truth_resamples_an_rgb_file_and_states_its_error(files, tmp_path, capsys):
    import neuralbrdf as nb
    from neuralbrdf.evaluation.truth import RESAMPLING_LOGCOS_KEY, RESAMPLING_PAIRS_KEY

    out = tmp_path / "truth.onnx"
    assert cli(["export-truth", str(files["rgb"]), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "resampling of Mitsuba's measured plugin on a 90 x 45 x 24 table: hemisphere log-cos RMSE" in printed
    truth = nb.load(out)
    assert (truth.kind, truth.material, truth.is_spectral) == ("reference", "closed_rgb", False)
    metadata = truth._evaluator.model.metadata
    assert float(metadata[RESAMPLING_LOGCOS_KEY]) <= 0.005 and int(metadata[RESAMPLING_PAIRS_KEY]) >= 20_000
    assert out.stat().st_size < 1.5 * 2**20
    wi, wo = _pairs(5000, max_theta=80.0, seed=3)  # checked here against the closed form, not the plugin
    assert _logcos(truth(wi, wo), closed_form(wi, wo, False), wi) <= 0.005


@needs_shared
def test_export_truth_of_the_real_file_is_within_target(tmp_path):
    from neuralbrdf.evaluation.truth import RESAMPLING_LOGCOS_KEY, load_truth

    truth = load_truth(str(SHARED_FILE))
    assert float(truth.kind_metadata[RESAMPLING_LOGCOS_KEY]) <= 0.005


@pytest.mark.slow
def test_export_truth_of_a_spectral_file_is_within_target(files, tmp_path):
    import neuralbrdf as nb
    from neuralbrdf.evaluation.truth import RESAMPLING_LOGCOS_KEY

    truth = nb.truth(files["spectral"], tmp_path / "spec.onnx")
    assert truth.is_spectral and truth.wavelength_range_nm == (400.0, 700.0)
    assert float(truth._evaluator.model.metadata[RESAMPLING_LOGCOS_KEY]) <= 0.005
    assert (tmp_path / "spec.onnx").stat().st_size < 13 * 2**20
    wi, wo = _pairs(2000, max_theta=80.0, seed=4)
    bands = CALIBRATED_WAVELENGTHS_NM
    values = np.stack([truth(wi, wo, nm) for nm in bands], axis=1)
    assert _logcos(values, closed_form(wi, wo, True, bands), wi) <= 0.005


def test_evaluate_scores_a_model_against_the_measurement_through_the_plugin(files, resampled, tmp_path):
    import neuralbrdf as nb

    model = resampled
    scores = nb.evaluate(model, files["rgb"], tmp_path / "eval", images=False)
    assert (scores["truth_kind"], scores["truth_material"], scores["notes"]) == ("measurement", "closed_rgb", [])
    recorded = float(model._evaluator.model.metadata["neuralbrdf.reference.resampling_logcos_rmse"])
    assert 0 < scores["hemisphere_logcos_rmse"] <= 2 * recorded + 1e-4
    with pytest.raises(InputError, match="an RGB measurement: Mitsuba's measured plugin renders it only in RGB"):
        nb.evaluate(model, files["rgb"], tmp_path / "eval2", variant="llvm_ad_spectral")


def test_a_measurement_is_rendered_with_the_models_proposal(files, resampled, tmp_path, monkeypatch):
    """Matched paths the other way round: the model samples its own way, the measurement with the model's."""
    import neuralbrdf as nb
    from neuralbrdf.evaluation import evaluate as evaluation

    calls = []

    def fake_render(path, settings, seed, proposal=None, scene=None):
        calls.append((path.name, settings.variant, proposal and proposal.name))
        return np.full((2, 2, 3), 0.5, dtype=np.float32)

    monkeypatch.setattr(evaluation, "_render", fake_render)
    nb.evaluate(resampled, files["rgb"], tmp_path / "eval", spp=2, resolution=16)
    assert calls == [("resampled.onnx", "llvm_ad_rgb", None)] + [("closed_rgb.bsdf", "llvm_ad_rgb", "resampled.onnx")] * 2


@pytest.mark.slow
def test_a_measurement_replaces_the_named_material_of_a_users_scene(files, tmp_path):
    import json

    from test_evaluate_scene import SCENE

    import neuralbrdf as nb

    nb.truth(files["rgb"], tmp_path / "truth.onnx")  # the scene's own material, and the model scored
    (tmp_path / "scene.xml").write_text(SCENE.format(second=""))
    out = tmp_path / "eval"
    assert cli(["evaluate", str(tmp_path / "truth.onnx"), "--truth", str(files["rgb"]), "--scene",
                str(tmp_path / "scene.xml"), "--out-dir", str(out), "--spp", "4"]) == 0
    result = json.loads((out / "evaluation.json").read_text())
    assert (result["scene_material"], result["truth_kind"], result["variant"]) == ("ball", "measurement", "llvm_ad_rgb")
    assert result["resolution"] == [20, 14] and result["image_delta_e2000_mean"] < result["noise"]["image_delta_e2000_mean"]


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["rgb", "spectral"])
def test_evaluate_renders_the_truth_with_the_measured_plugin(files, tmp_path, kind):
    import neuralbrdf as nb

    model = nb.truth(files[kind], tmp_path / "resampled.onnx")
    scores = nb.evaluate(model, files[kind], tmp_path / "eval", spp=16, resolution=32)
    assert scores["variant"] == ("llvm_ad_spectral" if kind == "spectral" else "llvm_ad_rgb")
    assert scores["image_delta_e2000_mean"] < 0.5 * scores["noise"]["image_delta_e2000_mean"]
    assert "sampled as this model samples" in scores["noise"]["what"]  # the noise depends on the model here
    assert all((tmp_path / "eval" / name).is_file() for name in ("truth.png", "model.png", "comparison.png"))


@pytest.mark.slow
def test_the_truth_render_converges_to_the_measured_plugins_own(files):
    """The wrapper's eval is the plugin's (clipped) and a model's proposal leaves the image's expectation
    unchanged: its render and a render of Mitsuba's plain ``measured`` plugin, sampled its own way, agree
    within their noise."""
    import mitsuba as mi

    from neuralbrdf.evaluation.truth import export_truth
    from neuralbrdf.render.preview import set_variant

    proposal = files["rgb"].with_suffix(".onnx")
    export_truth(str(files["rgb"]), proposal)
    set_variant("llvm_ad_rgb")

    def scene(bsdf):
        return mi.load_dict({
            "type": "scene", "integrator": {"type": "path", "max_depth": 3},
            "sensor": {"type": "perspective", "fov": 40, "film": {"type": "hdrfilm", "width": 24, "height": 24},
                       "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0])},
            "sphere": {"type": "sphere", "bsdf": bsdf}, "sky": {"type": "constant", "radiance": 0.2},
            "light": {"type": "point", "position": [3, 3, 3], "intensity": 30.0}})

    plain = {"type": "measured", "filename": str(files["rgb"])}
    wrapped = {"type": "neuralbrdf_measured", "filename": str(files["rgb"]), "proposal": str(proposal)}
    images = [[np.asarray(mi.render(scene(b), spp=256, seed=s)).mean(axis=(0, 1)) for s in (0, 1)] for b in (plain, wrapped)]
    noise = np.abs(images[0][0] - images[0][1]) + np.abs(images[1][0] - images[1][1])
    difference = np.abs((images[0][0] + images[0][1]) - (images[1][0] + images[1][1])) / 2
    assert np.all(difference < 3 * noise + 1e-3 * images[0][0])


# --------------------------------------------------------------------------- study


def test_a_study_profile_takes_an_rgl_truth(files, tmp_path):
    from neuralbrdf.study.cell import render_variant, write_data
    from neuralbrdf.study.profile import load_profile

    profile = tmp_path / "rgl.yaml"
    profile.write_text("render: {spp: 2, resolution: 16}\ncost: {spp: 2, resolution: 16, repeats: 1, batch: 4096}\n"
                       f"materials:\n  - {{name: spec, truth: {files['spectral']}}}\n"
                       "variants:\n  - {name: abc, method: abc, config: configs/abc.yaml}\n")
    material = load_profile(str(profile)).materials[0]
    assert material.truth == str(files["spectral"]) and material.is_spectral
    spec = {"cell": {"plan": "DS3", "noise": 0.0, "seed": 0}, "plan": "DS3", "material": {"table": None, "truth": material.truth},
            "variant": {"render_variant": None}}
    assert read_table(write_data(spec, tmp_path / "data" / "spec.csv")).wavelengths.size == 31
    assert render_variant(spec, Path(material.truth)) == "llvm_ad_spectral"
    bad = tmp_path / "bad.bsdf"
    bad.write_bytes(b"not a tensor file at all")
    profile.write_text(profile.read_text().replace(str(files["spectral"]), str(bad)))
    with pytest.raises(InputError, match="not a readable RGL measurement: not a Mitsuba tensor_file"):
        load_profile(str(profile))


def test_round_off_below_zero_in_a_distribution_is_read_and_a_real_negative_is_refused(files, tmp_path):
    """The database's ilm_solo_m_68_rgb.bsdf holds a luminance of -3.98e-10: float round-off, readable."""
    fields = read_tensor_file(files["rgb"])
    peak = float(fields["luminance"].max())
    for value, readable in ((-1e-9 * peak, True), (-1e-3 * peak, False)):
        luminance = fields["luminance"].copy()
        luminance.flat[7] = value
        path = tmp_path / f"luminance_{readable}.bsdf"
        write_tensor_file(path, {**fields, "luminance": luminance})
        if readable:
            assert RglBsdf.load(path).description == RglBsdf.load(files["rgb"]).description
        else:
            with pytest.raises(InputError, match="field 'luminance': negative value"):
                RglBsdf.load(path)
