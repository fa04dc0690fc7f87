"""Surprises from outside, each one line: a FIFO, a symbolic-link loop or a dangling link given as
an input file, an infrared model given to ``export --model``, and options and query entries named
as options and keys (not as table columns)."""

import os

import pytest
from onnx_fixtures import write_lambert, write_spectral_lambert

from neuralbrdf.cli.main import main as cli
from neuralbrdf.errors import InputError
from neuralbrdf.explorer.launch import open_scene
from neuralbrdf.explorer.server import Viewer
from neuralbrdf.explorer.views import State


@pytest.fixture(scope="module")
def odd_paths(tmp_path_factory):
    """A FIFO, a symbolic link to itself and one to nothing, each under every input suffix."""
    folder = tmp_path_factory.mktemp("odd")
    paths = {}
    for suffix in (".bsdf", ".onnx", ".binary", ".h5", ".xml", ".ckpt", ".csv"):
        fifo, loop, dangling = (folder / f"{name}{suffix}" for name in ("fifo", "loop", "dangling"))
        os.mkfifo(fifo)
        loop.symlink_to(loop)
        dangling.symlink_to(folder / f"nothing{suffix}")
        paths[suffix] = {"FIFO": fifo, "loop": loop, "dangling": dangling}
    return paths


EXPECTED = {"FIFO": "is a FIFO, not a regular file", "loop": "is a symbolic link that loops",
            "dangling": "is a broken symbolic link (to "}
#: A command reading each kind of file (``{path}`` the input, ``{out}`` an output).
READERS = {
    ".bsdf": ["sample", "{path}", "--plan", "DS3", "--out", "{out}.csv"],
    ".onnx": ["evaluate", "{path}", "--truth", "{path}", "--out-dir", "{out}", "--no-render"],
    ".binary": ["sample", "{path}", "--plan", "DS3", "--out", "{out}.csv"],
    ".h5": ["sample", "{path}", "--plan", "DS3", "--out", "{out}.csv"],
    ".xml": ["render", "--scene", "{path}", "--out", "{out}.png"],
    ".ckpt": ["export", "--ckpt", "{path}", "--out", "{out}.onnx"],
    ".csv": ["to-rgb", "{path}", "--out", "{out}.csv"],
}


@pytest.mark.parametrize("suffix", READERS)
def test_a_fifo_or_a_link_loop_is_named_as_such_not_as_missing(odd_paths, tmp_path, capsys, suffix):
    """Both were "no such file"; a FIFO opened for reading would block for ever."""
    for what, path in odd_paths[suffix].items():
        out = tmp_path / f"{what}_out"
        assert cli([a.format(path=path, out=out) for a in READERS[suffix]]) == 2, (suffix, what)
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{path}: {EXPECTED[what]}" in err[0], (suffix, what, err)
        assert not list(tmp_path.glob(f"{what}_out*"))


def test_export_model_names_why_an_infrared_model_gets_no_rgb_head(tmp_path, capsys):
    """It asked for "a spectral model without an RGB head" when given exactly that."""
    infrared = write_spectral_lambert(tmp_path / "ir.onnx", wavelength_range=(700.0, 1000.0))
    out = tmp_path / "out.onnx"
    assert cli(["export", "--model", str(infrared), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nothing to add: the model covers 700-1000 nm" in err[0] and "--fast" in err[0], err
    assert not out.exists()


def test_options_and_query_entries_are_named_as_such(tmp_path):
    """``--port`` and a bad query entry were called a "column"."""
    model = write_lambert(tmp_path / "m.onnx")
    scene = open_scene([model])
    with pytest.raises(InputError) as error:
        Viewer(scene, port=70000)
    assert str(error.value).startswith("option '--port': expected a port from 0 to 65535")
    with pytest.raises(InputError) as error:
        State().updated({"theta_i": "steep"})
    assert str(error.value).startswith("key 'theta_i': expected a number")
    with pytest.raises(InputError) as error:
        scene.view("nope", State())
    assert str(error.value).startswith("key 'views': unknown view 'nope'")
