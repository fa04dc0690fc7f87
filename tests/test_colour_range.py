"""One wavelength-range rule for every colour (neuralbrdf.data.colorimetry.colour_problem):
``to-rgb``, ``plot``, the viewer and an exported RGB head compute a colour only from a range that
holds the CIE observer's weight over 400-700 nm; a table of 500-800 nm lost every blue with exit 0."""

import dataclasses

import numpy as np
import pytest
from onnx_fixtures import write_lambert, write_spectral_lambert

from neuralbrdf.cli.main import main as cli
from neuralbrdf.data.colorimetry import colour_problem
from neuralbrdf.data.table import read_table, write_table
from neuralbrdf.explorer.launch import open_scene
from neuralbrdf.explorer.views import State
from neuralbrdf.lod.fast_paths import rgb_head_problem


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    """The virtual gold on DS2 (400-700 nm) and the same values labelled 500-800 and 300-600 nm."""
    folder = tmp_path_factory.mktemp("colour")
    visible = folder / "visible.csv"
    assert cli(["simulate", "--material", "gold", "--plan", "DS2", "--truth", "--out", str(visible)]) == 0
    table = read_table(visible)
    shifted = {}
    for low in (500.0, 300.0):
        path = folder / f"from_{low:.0f}.csv"
        write_table(dataclasses.replace(table, wavelengths=table.wavelengths + (low - 400.0)), path)
        shifted[low] = path
    return visible, shifted


@pytest.mark.parametrize("low", [500.0, 300.0])
@pytest.mark.parametrize("command", ["to-rgb", "plot"])
def test_a_table_without_the_visible_range_is_refused_naming_its_file(tables, tmp_path, capsys, command, low):
    _, shifted = tables
    out = tmp_path / ("out.csv" if command == "to-rgb" else "out.png")
    assert cli([command, str(shifted[low]), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"neuralbrdf {command}: error: {shifted[low]}: the table covers "
                                               f"{low:g}-{low + 300:g} nm, which holds"), err
    assert "no colour is computed from it" in err[0] and not out.exists()


def test_the_rule_is_one_for_tables_and_rgb_heads():
    for low, high in ((400.0, 700.0), (380.0, 780.0), (500.0, 800.0), (300.0, 600.0), (410.0, 700.0), (700.0, 1000.0)):
        assert (colour_problem((low, high), "x") is None) == (rgb_head_problem((low, high)) is None), (low, high)
    assert colour_problem((400.0, 700.0), "x") is None and colour_problem((500.0, 800.0), "x") is not None


def test_the_viewer_shows_no_colour_for_a_model_or_table_without_the_visible_range(tables, tmp_path):
    """It showed colour for such a model with no caveat: now it leaves it out of every colour and says why."""
    _, shifted = tables
    rgb = write_lambert(tmp_path / "rgb.onnx")
    infrared = write_spectral_lambert(tmp_path / "ir.onnx", wavelength_range=(500.0, 800.0))
    scene = open_scene([rgb, infrared], table=read_table(shifted[500.0]), table_label="from_500.csv")
    described = {s["label"]: s for s in scene.describe()["sources"]}
    assert described["rgb.onnx"]["no_colour"] is None
    assert described["ir.onnx"]["no_colour"].startswith("the model covers 500-800 nm")
    assert described["ir.onnx"]["rgb_rule"] is None
    luminance = scene.view("inplane", State(channel="Y", theta_i=30.0))
    assert [c["label"] for c in luminance["curves"]] == ["rgb.onnx"] and luminance["missing"] == ["ir.onnx"]
    assert luminance["measured"] is None  # the table has no colour either
    at_600 = scene.view("inplane", State(channel="wavelength", wavelength=600.0, theta_i=30.0))
    assert [c["label"] for c in at_600["curves"]] == ["ir.onnx"] and at_600["measured"] is not None
    hemisphere = scene.view("hemisphere", State(hemisphere="colour"))
    assert [m["label"] for m in hemisphere["maps"]] == ["rgb.onnx"] and hemisphere["missing"] == ["ir.onnx"]
    sphere = scene.view("sphere", State(sphere="colour"))
    assert [i["label"] for i in sphere["images"]] == ["rgb.onnx"] and sphere["missing"] == ["ir.onnx"]
    spectrum = scene.view("spectrum", State())
    assert [c["label"] for c in spectrum["colours"]] == ["rgb.onnx"]
    assert [c["label"] for c in spectrum["curves"]] == ["ir.onnx"] and np.all(np.isfinite(spectrum["curves"][0]["y"]))
