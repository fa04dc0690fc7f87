"""``neuralbrdf evaluate --scene``: model and truth swapped into a user's scene by material name."""

import json

import pytest

from neuralbrdf.cli.main import main

SCENE = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="20"/><integer name="height" value="14"/></film>
    </sensor>
    <bsdf type="neuralbrdf" id="ball"><string name="filename" value="truth.onnx"/></bsdf>
    {second}
    <shape type="sphere"><float name="radius" value="1"/><ref id="ball"/></shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.5"/><lookat origin="-2, 3, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <emitter type="area"><rgb name="radiance" value="20, 20, 20"/></emitter>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="0.3, 0.3, 0.3"/></emitter>
</scene>
"""
SECOND = """<shape type="sphere"><point name="center" value="3, 0, -2"/><float name="radius" value="0.5"/>
        <bsdf type="neuralbrdf" id="other"><string name="filename" value="truth.onnx"/></bsdf></shape>"""


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    import neuralbrdf as nb

    folder = tmp_path_factory.mktemp("scene")
    nb.truth("virtual:gold", folder / "truth.onnx")
    nb.truth("virtual:gonio", folder / "model.onnx")
    (folder / "one.xml").write_text(SCENE.format(second=""))
    (folder / "two.xml").write_text(SCENE.format(second=SECOND))
    return folder


def test_model_and_truth_are_swapped_into_the_named_material(scene, tmp_path, capsys):
    out = tmp_path / "eval"
    assert main(["evaluate", str(scene / "model.onnx"), "--truth", str(scene / "truth.onnx"), "--scene",
                 str(scene / "two.xml"), "--material", "ball", "--out-dir", str(out), "--spp", "2",
                 "--variant", "llvm_ad_rgb"]) == 0
    result = json.loads((out / "evaluation.json").read_text())
    assert result["scene"] == str(scene / "two.xml") and result["scene_material"] == "ball"
    assert result["resolution"] == [20, 14]  # the scene's own film
    assert result["model_material"] == "gonio" and result["image_delta_e2000_mean"] > 1.0
    assert all((out / name).is_file() for name in ("model.png", "truth.png", "error_map.png", "comparison.png"))
    assert "image_delta_e2000_mean" in capsys.readouterr().out


@pytest.mark.parametrize("scene_file, extra, message", [
    ("two.xml", [], "has 2 neuralbrdf materials (ball, other); name one with --material"),
    ("one.xml", ["--material", "gold"], "no neuralbrdf material named 'gold'; it has ball"),
    (None, ["--material", "ball"], "material names a material of a scene: give the scene too"),
])
def test_an_ambiguous_or_unknown_material_is_one_line_before_any_work(scene, tmp_path, capsys, scene_file, extra, message):
    args = ["evaluate", str(scene / "model.onnx"), "--truth", str(scene / "truth.onnx"), "--out-dir", str(tmp_path / "e")]
    args += ["--scene", str(scene / scene_file)] if scene_file else []
    assert main([*args, *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "e").exists()
