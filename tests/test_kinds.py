"""The kind registry: one module per kind, found without a list to edit; the
exporter, the contract check and the renderer's proposal all ask it."""

import subprocess
import sys

import pytest

import onnx_fixtures as fx
from neuralbrdf import kinds
from neuralbrdf.errors import InputError
from neuralbrdf.kinds import CHECKPOINT_KIND_KEY, Kind
from neuralbrdf.lightning.abc_module import AbcFitModule
from neuralbrdf.lightning.auto_fit import AutoFitModule
from neuralbrdf.lightning.common import WritesKind
from neuralbrdf.lightning.latent_fit_module import LatentFitModule
from neuralbrdf.lightning.pca_fit import PcaFitModule
from neuralbrdf.lightning.spectral_mlp_module import SpectralMlpModule
from neuralbrdf.onnx_contract import generic_metadata

TOY_KIND = '''
from neuralbrdf.kinds import Kind

KIND = Kind(name="toy", summary="a kind added as one file")
'''


def test_the_shipped_kinds_are_registered_with_what_the_library_needs():
    assert kinds.names() == ["abc", "auto", "nlb", "nlb_spectral", "pca", "reference", "spectral_mlp", "table"]
    for name in kinds.names():
        kind = kinds.get(name)
        assert kind.name == name and kind.summary
        assert kind.proposal in ("fitted_ggx", "abc_lobe", "chosen")
    trained = {name for name in kinds.names() if kinds.get(name).from_checkpoint is not None}
    assert trained == {"abc", "auto", "nlb", "nlb_spectral", "pca", "spectral_mlp"}
    assert kinds.get("spectral_mlp").spectral_only and not kinds.get("nlb").spectral_only
    assert kinds.get("abc").proposal == "abc_lobe" and kinds.get("auto").proposal == "chosen"


def test_proposal_names_are_the_renderers():
    mitsuba = pytest.importorskip("mitsuba")
    mitsuba.set_variant("llvm_ad_rgb")
    from neuralbrdf.render.sampling import PROPOSALS

    assert {kinds.get(name).proposal for name in kinds.names()} <= set(PROPOSALS)


def test_unknown_kind_names_the_registered_ones():
    with pytest.raises(InputError, match=r"unknown model kind 'gan'; expected one of \['abc', 'auto', 'nlb'"):
        kinds.get("gan")


@pytest.mark.parametrize("module", [SpectralMlpModule, AbcFitModule, LatentFitModule, AutoFitModule, PcaFitModule])
def test_every_fitted_model_module_writes_a_registered_kind(module):
    assert issubclass(module, WritesKind)
    assert kinds.get(module.KIND).from_checkpoint is not None


def test_the_shared_hook_writes_the_kind_into_the_checkpoint():
    checkpoint = {}
    SpectralMlpModule().on_save_checkpoint(checkpoint)
    assert checkpoint[CHECKPOINT_KIND_KEY] == "spectral_mlp"


def test_a_new_kind_is_one_new_file(tmp_path, monkeypatch):
    path = fx.save(fx.tiny_rgb_model(generic_metadata("toy", "fixture", "test")), tmp_path / "toy.onnx")
    with pytest.raises(InputError, match="unknown model kind 'toy'"):
        kinds.load_model(path)
    extra = tmp_path / "more_kinds"
    extra.mkdir()
    (extra / "toy.py").write_text(TOY_KIND)
    monkeypatch.setattr(kinds, "__path__", [*kinds.__path__, str(extra)])
    monkeypatch.setattr(kinds, "_REGISTRY", {})
    assert "toy" in kinds.names()
    model = kinds.load_model(path)
    assert (model.kind, model.details) == ("toy", None)
    assert kinds.get("toy").proposal == "fitted_ggx"
    monkeypatch.delitem(sys.modules, "neuralbrdf.kinds.toy")


def test_a_module_without_kind_is_refused(tmp_path, monkeypatch):
    extra = tmp_path / "broken_kinds"
    extra.mkdir()
    (extra / "nothing_here.py").write_text("VALUE = 1\n")
    monkeypatch.setattr(kinds, "__path__", [*kinds.__path__, str(extra)])
    monkeypatch.setattr(kinds, "_REGISTRY", {})
    with pytest.raises(TypeError, match="defines no KIND"):
        kinds.names()
    monkeypatch.delitem(sys.modules, "neuralbrdf.kinds.nothing_here")


def test_a_spectral_only_kind_refuses_an_rgb_file(tmp_path):
    path = fx.save(fx.tiny_rgb_model(generic_metadata("spectral_mlp", "fixture", "test")), tmp_path / "m.onnx")
    with pytest.raises(InputError, match="spectral_mlp model must take a 'wavelength' input"):
        kinds.load_model(path)


def test_checking_and_exporting_never_load_mitsuba():
    code = ("import sys, neuralbrdf.kinds, neuralbrdf.onnx_export, neuralbrdf.cli.export_command; "
            "loaded = [m for m in ('mitsuba', 'drjit') if m in sys.modules]; assert not loaded, loaded")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_checking_a_file_loads_neither_pytorch_nor_mitsuba(tmp_path):
    path = fx.write_abc_like(tmp_path / "abc.onnx", fx.AbcMetadata((0.1, 0.2, 0.3), (1.0, 0.8, 0.6), 60.0, 1.3, 1.5))
    code = ("import sys; from neuralbrdf import kinds; "
            f"model = kinds.load_model({str(path)!r}); assert model.details.B == 60.0; "
            "loaded = [m for m in ('torch', 'mitsuba', 'drjit') if m in sys.modules]; assert not loaded, loaded")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_kind_dataclass_defaults_describe_a_neural_kind():
    kind = Kind(name="x", summary="y")
    assert (kind.spectral_only, kind.proposal, kind.from_checkpoint) == (False, "fitted_ggx", None)


@pytest.mark.parametrize(
    ("checkpoint", "kind"),
    [
        ({"hyper_parameters": {"_class_path": "neuralbrdf.lightning.spectral_mlp_module.SpectralMlpModule"}},
         "spectral_mlp"),
        ({"hyper_parameters": {"_class_path": "neuralbrdf.lightning.latent_fit_module.LatentFitModule"}}, "nlb"),
        ({"material_names": ["a"], "nlb_config": {}}, "nlb"),
        ({"abc_parameters": {}, "material": "m"}, "abc"),
        ({CHECKPOINT_KIND_KEY: "abc"}, "abc"),
    ],
    ids=["spectral by class", "nlb by class", "nlb by layout", "abc by layout", "by key"],
)
def test_checkpoints_without_the_kind_key_are_recognised_by_their_layout(checkpoint, kind):
    assert kinds.checkpoint_kind(checkpoint, "old.ckpt").name == kind


@pytest.mark.parametrize("checkpoint", [{}, {CHECKPOINT_KIND_KEY: "reference"}, {"state_dict": {}}])
def test_a_checkpoint_of_no_trained_kind_is_refused_naming_the_key(checkpoint):
    with pytest.raises(InputError, match=r"unknown checkpoint kind .*expected one of \['abc', 'auto', 'nlb', 'nlb_spectral', 'pca', 'spectral_mlp'\]") as info:
        kinds.checkpoint_kind(checkpoint, "x.ckpt")
    assert info.value.key == CHECKPOINT_KIND_KEY and str(info.value.path) == "x.ckpt"


def test_the_shipped_pretrained_networks_name_a_class_that_exists():
    """Lightning rebuilds the module of --ckpt_path (validate, test, --resume) from its class path."""
    import importlib

    import torch

    from neuralbrdf.shipped import PRETRAINED_DIR

    for path in sorted(PRETRAINED_DIR.glob("*.ckpt")):
        class_path = torch.load(path, map_location="cpu", weights_only=True)["hyper_parameters"]["_class_path"]
        module, _, name = class_path.rpartition(".")
        assert hasattr(importlib.import_module(module), name), (path.name, class_path)
