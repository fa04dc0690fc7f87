"""A training configuration that does not parse ends with one line naming the key, where it was
given (flag or file) and the nearest valid names; no usage dump, no run directory."""

import pytest

from neuralbrdf.lightning.run import main

pytestmark = pytest.mark.filterwarnings("ignore:LightningCLI's args parameter is intended")


def one_error(capsys) -> str:
    """The single line the command printed, checked for what a usage dump would hold."""
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("neuralbrdf train: error: ") and "NoneType" not in err and "usage:" not in err, err
    return lines[0]


def run_fails(args, tmp_path, capsys) -> str:
    run_dir = tmp_path / "run"
    assert main([*args, "--run_dir", str(run_dir)]) == 2
    assert not run_dir.exists()
    return one_error(capsys)


def test_a_misspelt_model_option_on_the_command_line(tmp_path, capsys):
    line = run_fails(["fit", "--config", "abc", "--model.n_start", "4"], tmp_path, capsys)
    assert line.startswith("neuralbrdf train: error: --model.n_start: AbcFitModule has no option 'n_start'; "
                           "did you mean n_starts?")
    assert "(valid: bounds, max_evaluations, n_starts, seed)" in line


def test_a_single_source_option_of_a_latent_fit_points_to_its_sources_list(tmp_path, capsys):
    line = run_fails(["fit", "--config", "nlb_spectral", "--data.virtual", "gold"], tmp_path, capsys)
    assert line.startswith("neuralbrdf train: error: --data.virtual: LatentFitData has no option 'virtual'; "
                           "one virtual source is a list of one: --data.sources '[{\"virtual\": ...}]'")


def test_a_misspelt_key_in_a_config_file_names_the_file(tmp_path, capsys):
    overlay = tmp_path / "mine.yaml"
    overlay.write_text("model:\n  init_args:\n    n_start: 4\n")
    line = run_fails(["fit", "--config", "abc", "--config", str(overlay)], tmp_path, capsys)
    assert line.startswith(f"neuralbrdf train: error: {overlay}: model.n_start: AbcFitModule has no option 'n_start'; "
                           "did you mean n_starts?")


def test_a_misspelt_trainer_key_in_a_file_suggests_the_nearest_names(tmp_path, capsys):
    overlay = tmp_path / "mine.yaml"
    overlay.write_text("trainer:\n  max_epoch: 3\n")
    line = run_fails(["fit", "--config", "spectral_mlp", "--config", str(overlay)], tmp_path, capsys)
    assert line.startswith(f"neuralbrdf train: error: {overlay}: trainer.max_epoch: Trainer has no option 'max_epoch'; "
                           "did you mean max_epochs")


@pytest.mark.parametrize("flag, valid", [("--data.pth", "did you mean path?"),
                                         ("--model.optimizer.lrr", "did you mean lr?"),
                                         ("--trainer.max_epochz", "did you mean max_epochs"),
                                         ("--foo", "valid: ckpt_path, data, model")])
def test_every_level_of_key_names_its_options(tmp_path, capsys, flag, valid):
    config = "spectral_mlp" if "optimizer" in flag else "abc"
    line = run_fails(["fit", "--config", config, flag, "3"], tmp_path, capsys)
    assert line.startswith(f"neuralbrdf train: error: {flag}: ") and valid in line, line


def test_a_bad_value_names_the_flag_not_the_file_that_set_it_first(tmp_path, capsys):
    line = run_fails(["fit", "--config", "abc", "--trainer.max_epochs", "many"], tmp_path, capsys)
    assert line == "neuralbrdf train: error: --trainer.max_epochs: expected int, got 'many'"
    line = run_fails(["fit", "--config", "abc", "--model.n_starts=lots"], tmp_path, capsys)
    assert line == "neuralbrdf train: error: --model.n_starts: expected int, got 'lots'"


def test_an_unknown_config_lists_the_shipped_ones(tmp_path, capsys):
    line = run_fails(["fit", "--config", "abcd"], tmp_path, capsys)
    assert "abcd: no such configuration file" in line and "did you mean abc?" in line
    assert "shipped: abc, auto, nlb_latent," in line and "nlb_spectral_pretrain, pca, spectral_mlp" in line


def test_an_unknown_subcommand_and_a_missing_config(tmp_path, capsys):
    assert run_fails(["fitt", "--config", "abc"], tmp_path, capsys) == (
        "neuralbrdf train: error: unknown subcommand 'fitt'; did you mean fit? (valid: fit, test, validate)")
    assert "--config NAME" in run_fails(["fit"], tmp_path, capsys)


def test_lightnings_usage_names_the_real_command(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["fit", "--config", "abc", "--help"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.startswith("usage: neuralbrdf train [options] fit")
