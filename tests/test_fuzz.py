"""Property-based tests of the readers of untrusted files (docs/robustness.md).

For any byte string, and for any mutation of a valid file, the CSV reader, the BRDF table and
GCMS readers (and :func:`~neuralbrdf.data.loading.load_measurement`), the ONNX contract check
and the calibration command either return a result or raise
:class:`~neuralbrdf.errors.InputError` — never another exception — and a command that fails
leaves no output file.  Example counts are kept small (:data:`EXAMPLES`) so the default suite
stays fast; raise them with ``NEURALBRDF_FUZZ_EXAMPLES=2000`` for a long run.
"""

import os
import shutil
import tempfile
import warnings
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from neuralbrdf.cli.main import main as cli
from neuralbrdf.data.csvio import read_numeric_csv
from neuralbrdf.data.gcms import read_gcms
from neuralbrdf.data.loading import load_measurement
from neuralbrdf.data.table import read_table
from neuralbrdf.errors import InputError
from neuralbrdf.kinds import load_model

import onnx_fixtures as fx

#: Examples per property by default.
EXAMPLES = int(os.environ.get("NEURALBRDF_FUZZ_EXAMPLES", "100"))
#: The default run is reproducible (the same examples every time); a long run explores afresh.
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize="NEURALBRDF_FUZZ_EXAMPLES" not in os.environ,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

READERS = {
    "numeric csv": read_numeric_csv,
    "brdf table": read_table,
    "gcms raw": read_gcms,
    "measurement": load_measurement,
}


@pytest.fixture(scope="module")
def valid_files(tmp_path_factory):
    """Small valid files to mutate: a spectral table, an RGB table, a GCMS sample and its reference."""
    folder = tmp_path_factory.mktemp("valid")
    files = {}
    for name, args in {
        "spectral": ["simulate", "--material", "gold", "--plan", "DS4", "--truth"],
        "gcms": ["simulate", "--material", "gold", "--plan", "DS4"],
        "reference": ["simulate", "--material", "munsell_n9", "--plan", "DS4"],
    }.items():
        assert cli([*args, "--out", str(folder / f"{name}.csv")]) == 0
        files[name] = (folder / f"{name}.csv").read_bytes()
    assert cli(["to-rgb", str(folder / "spectral.csv"), "--out", str(folder / "rgb.csv")]) == 0
    files["rgb"] = (folder / "rgb.csv").read_bytes()
    fx.save(fx.tiny_rgb_model(), folder / "model.onnx")
    files["onnx"] = (folder / "model.onnx").read_bytes()
    return files


def _accepts_or_input_error(read, path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # clipping notes are expected on mutated values
        try:
            read(path)
        except InputError:
            pass


#: Text edits that keep a file CSV-like: replace a cell, drop or repeat a line, cut the file.
CELL_VALUES = st.sampled_from(["", "nan", "-inf", "1e400", "-1000", "0", "-0", "x", "1,2", '"', "1e-320", " 5 ", "９"])


@st.composite
def mutations(draw, data: bytes):
    text = data.decode()
    lines = text.splitlines()
    for _ in range(draw(st.integers(1, 3))):
        if not lines:
            break
        kind = draw(st.sampled_from(["cell", "drop", "repeat", "cut", "swap", "bytes"]))
        k = draw(st.integers(0, len(lines) - 1))
        if kind == "cell":
            cells = lines[k].split(",")
            cells[draw(st.integers(0, len(cells) - 1))] = draw(CELL_VALUES | st.text(max_size=6))
            lines[k] = ",".join(cells)
        elif kind == "drop":
            del lines[k]
        elif kind == "repeat":
            lines.insert(draw(st.integers(0, len(lines))), lines[k])
        elif kind == "cut":
            lines[k] = lines[k][: draw(st.integers(0, len(lines[k])))]
            lines = lines[: k + 1]
        elif kind == "swap":
            j = draw(st.integers(0, len(lines) - 1))
            lines[k], lines[j] = lines[j], lines[k]
        else:
            lines[k] = lines[k] + draw(st.binary(max_size=8)).decode("latin-1")
    return "\n".join(lines).encode("utf-8", "surrogatepass") if lines else b""


def _write(folder: Path, name: str, data: bytes) -> Path:
    path = folder / name
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("reader", list(READERS))
@FUZZ
@given(data=st.binary(max_size=400))
def test_any_bytes_are_read_or_refused(tmp_path, reader, data):
    _accepts_or_input_error(READERS[reader], _write(tmp_path, "any.csv", data))


@pytest.mark.parametrize(
    "source, reader",
    [("spectral", "brdf table"), ("rgb", "measurement"), ("gcms", "gcms raw"), ("gcms", "numeric csv")],
)
@FUZZ
@given(data=st.data())
def test_mutated_valid_files_are_read_or_refused(tmp_path, valid_files, source, reader, data):
    mutated = data.draw(mutations(valid_files[source]))
    _accepts_or_input_error(READERS[reader], _write(tmp_path, "mutated.csv", mutated))


@FUZZ
@given(data=st.data())
def test_mutated_calibration_inputs_give_a_table_or_exit_2_and_no_output(valid_files, data):
    which = data.draw(st.sampled_from(["gcms", "reference", "both"]))
    sample = valid_files["gcms"] if which == "reference" else data.draw(mutations(valid_files["gcms"]))
    reference = valid_files["reference"] if which == "gcms" else data.draw(mutations(valid_files["reference"]))
    folder = Path(tempfile.mkdtemp())
    try:
        out = folder / "out" / "table.csv"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            status = cli(["calibrate", str(_write(folder, "s.csv", sample)), "--reference",
                          str(_write(folder, "r.csv", reference)), "--out", str(out)])
        assert status in (0, 2)
        if status == 0:
            read_table(out)  # what calibrate writes, the table reader accepts
        else:
            assert not (folder / "out").exists()
        assert sorted(p.name for p in folder.iterdir()) == sorted(["s.csv", "r.csv", *(["out"] if status == 0 else [])])
    finally:
        shutil.rmtree(folder)


@FUZZ
@given(data=st.binary(max_size=600))
def test_any_bytes_fail_the_onnx_contract_check_cleanly(tmp_path, data):
    _accepts_or_input_error(load_model, _write(tmp_path, "any.onnx", data))


@FUZZ
@given(data=st.data())
def test_mutated_onnx_files_pass_or_fail_the_contract_check_cleanly(tmp_path, valid_files, data):
    raw = bytearray(valid_files["onnx"])
    for _ in range(data.draw(st.integers(1, 4))):
        kind = data.draw(st.sampled_from(["flip", "cut", "insert"]))
        k = data.draw(st.integers(0, len(raw) - 1))
        if kind == "flip":
            raw[k] ^= 1 << data.draw(st.integers(0, 7))
        elif kind == "cut":
            del raw[k:]
            if not raw:
                break
        else:
            raw[k:k] = data.draw(st.binary(min_size=1, max_size=8))
    _accepts_or_input_error(load_model, _write(tmp_path, "mutated.onnx", bytes(raw)))


@FUZZ
@given(data=st.data())
def test_mutated_tables_convert_to_rgb_or_exit_2_and_no_output(valid_files, data):
    mutated = data.draw(mutations(valid_files["spectral"]))
    folder = Path(tempfile.mkdtemp())
    try:
        out = folder / "rgb.csv"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            status = cli(["to-rgb", str(_write(folder, "t.csv", mutated)), "--out", str(out)])
        assert status in (0, 2)
        assert out.exists() == (status == 0)
        assert len(list(folder.iterdir())) == 1 + (status == 0)  # no temporary left behind
    finally:
        shutil.rmtree(folder)
