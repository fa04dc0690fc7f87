"""Every checkpoint a user names is refused in one line naming it when it is missing, cut short,
empty, not PyTorch's or of another model: ``train fit/validate/test --ckpt_path``,
``--model.checkpoint``, ``--model.warm_start`` and ``neuralbrdf export --ckpt``."""

from pathlib import Path

import pytest
import torch

from neuralbrdf.checkpoints import read_checkpoint
from neuralbrdf.cli.export_command import main as export
from neuralbrdf.errors import InputError
from neuralbrdf.lightning.run import main as train
from neuralbrdf.shipped import PRETRAINED_DIR

pytestmark = pytest.mark.filterwarnings("ignore:LightningCLI's args parameter is intended")

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
CUT_SHORT = "not a readable PyTorch checkpoint: cut short or damaged (2000 bytes; the end of the data is missing)"
#: A small pretraining corpus: the warm start is read when the fit sets up, after the data.
TINY_PRETRAINING = ("--data.batches_per_epoch", "1", "--data.val_batches", "1", "--data.num_workers", "0",
                    "--data.batch_size", "64", "--data.n_analytic", "8", "--model.n_materials", "8",
                    "--data.proxy_dir", "null")



@pytest.fixture
def cut_short(tmp_path) -> Path:
    """A checkpoint cut to its first 2000 bytes, as a copy interrupted part-way leaves it."""
    whole = tmp_path / "whole.ckpt"
    torch.save({"state_dict": {"w": torch.arange(4096.0)}, "hyper_parameters": {}}, whole)
    path = tmp_path / "cut.ckpt"
    path.write_bytes(whole.read_bytes()[:2000])
    return path


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if ": error: " in line]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize(
    "stage",
    [["fit"], ["fit", "--resume"], ["validate"], ["test"]],
    ids=["fit", "fit --resume", "validate", "test"],
)
def test_ckpt_path_cut_short_is_one_line_naming_it(stage, cut_short, tmp_path, capsys):
    """Lightning read --ckpt_path before any check and printed torch's traceback."""
    run_dir = tmp_path / "run"
    status = train([*stage, "--config", "abc", "--run_dir", str(run_dir), "--ckpt_path", str(cut_short)])
    line = _one_error_line(capsys)
    assert status == 2 and line == f"neuralbrdf train: error: {cut_short}: {CUT_SHORT}; copy or save it again"
    assert not run_dir.exists()


def test_ckpt_path_of_another_model_is_one_line(tmp_path, capsys):
    """Lightning swapped the config's model for the checkpoint's and crashed on the data."""
    other = PRETRAINED_DIR / "nlb_compact.ckpt"
    status = train(["validate", "--config", "abc", "--run_dir", str(tmp_path / "run"), "--ckpt_path", str(other)])
    line = _one_error_line(capsys)
    assert status == 2 and line == (f"neuralbrdf train: error: {other}: checkpoint to evaluate holds a NlbPretrainModule "
                                    "model but the config's model is AbcFitModule; give the config it was trained with")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("config", ["nlb_latent", "nlb_spectral"])
def test_model_checkpoint_cut_short_is_one_line(config, cut_short, tmp_path, capsys):
    status = train(["fit", "--config", config, "--run_dir", str(tmp_path / "run"),
                    "--model.checkpoint", str(cut_short)])
    assert status == 2 and _one_error_line(capsys).startswith(f"neuralbrdf train: error: {cut_short}: {CUT_SHORT}")
    assert not (tmp_path / "run").exists()


def test_warm_start_cut_short_is_one_line(cut_short, tmp_path, capsys):
    status = train(["fit", "--config", "nlb_pretrain", "--run_dir", str(tmp_path / "run"), "--trainer.max_epochs",
                    "1", *TINY_PRETRAINING, "--model.warm_start", str(cut_short)])
    assert status == 2 and _one_error_line(capsys).startswith(f"neuralbrdf train: error: {cut_short}: {CUT_SHORT}")
    assert not (tmp_path / "run").exists()


def test_export_ckpt_cut_short_is_one_line(cut_short, tmp_path, capsys):
    out = tmp_path / "model.onnx"
    assert export(["--ckpt", str(cut_short), "--out", str(out)]) == 2
    assert _one_error_line(capsys).startswith(f"neuralbrdf export: error: {cut_short}: {CUT_SHORT}")
    assert not out.exists()


def test_read_checkpoint_says_what_is_wrong_with_the_file(tmp_path):
    empty = tmp_path / "empty.ckpt"
    empty.write_bytes(b"")
    text = tmp_path / "notes.ckpt"
    text.write_text("not a checkpoint\n")
    legacy = tmp_path / "legacy.ckpt"
    torch.save({"w": torch.ones(64)}, legacy, _use_new_zipfile_serialization=False)
    assert read_checkpoint(legacy)["w"].shape == (64,)  # the legacy format still reads
    legacy_cut = tmp_path / "legacy_cut.ckpt"
    legacy_cut.write_bytes(legacy.read_bytes()[:100])
    for path, reason in (
        (empty, "the file is empty (0 bytes)"),
        (text, "17 bytes that are neither a zip archive (the PyTorch format) nor a legacy PyTorch pickle"),
        (legacy_cut, "cut short or damaged (100 bytes; the end of the data is missing); copy or save it again"),
    ):
        with pytest.raises(InputError) as info:
            read_checkpoint(path)
        assert str(info.value) == f"{path}: not a readable PyTorch checkpoint: {reason}"
