"""The study's cache, lock and exit status under bad input and damage (docs/study.md, docs/robustness.md): a changed
truth, damaged or foreign cached results, a cut-off run log, two studies on one folder, a worker
outliving its study, crashed and failed cells, bad profiles, and seeds that change something.

The study runs for real except for the two slow parts: cells run in a fake worker (:data:`FAKE_WORKER`:
it writes a result from ``cell.json`` at once, crashes for the variant ``crash``, fails for the
variant ``fails``) and truths are written by a fake exporter (a file naming its source)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from neuralbrdf.cli.main import main as cli
from neuralbrdf.errors import InputError
from neuralbrdf.folder_lock import folder_lock
from neuralbrdf.study import workers
from neuralbrdf.study.cells import MAIN_SEED, Cell, cell_key, plan_cells
from neuralbrdf.study.profile import load_profile

FAKE_WORKER = r"""
import json, os, sys
from pathlib import Path
for line in sys.stdin:
    folder = Path(line.strip())
    spec = json.loads((folder / "cell.json").read_text())
    variant = spec["variant"]["name"]
    if variant == "crash":
        os._exit(3)
    result = {**spec["cell"], "is_main": spec["is_main"], "key": spec["key"], "truth_sha256": spec["truth_sha256"],
              "failure": "optimizer_failure" if variant == "fails" else None,
              "message": "ABC fit: C at its upper bound" if variant == "fails" else None,
              "cost": {"fit_time_s": 1.0}, "error": {"hemisphere_logcos_rmse": 0.01 + 0.001 * spec["cell"]["seed"]},
              "truth": spec["truth"], "pid": os.getpid()}
    (folder / "result.json").write_text(json.dumps(result))
    print("done", flush=True)
"""

PROFILE = """render: {spp: 2, resolution: 16}
hemisphere_strata: [4, 5]
cost: {spp: 2, resolution: 16, repeats: 1, batch: 64}
materials:
  - {name: gold, truth: "TRUTH"}
variants:
VARIANTS
stability: {variants: [abc], plans: [DS1, DS2], noise: [0.0, 0.03], seeds: [0, 1]}
"""
ABC = '  - {name: abc, method: abc, config: configs/abc.yaml, speed_accuracy: false}\n'


def profile(tmp_path: Path, truth: str = "virtual:gold", variants: str = ABC) -> Path:
    path = tmp_path / "profile.yaml"
    path.write_text(PROFILE.replace("TRUTH", truth).replace("VARIANTS\n", variants))
    return path


@pytest.fixture
def fake(monkeypatch):
    """Fake cell workers and a fake truth exporter; the exported truths' sources are listed."""
    from neuralbrdf.evaluation import truth

    exported = []

    def export_truth(source, out):
        exported.append(source)
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(f"truth of {source}\n")

    monkeypatch.setattr(workers, "WORKER_COMMAND", (sys.executable, "-c", FAKE_WORKER))
    monkeypatch.setattr(truth, "export_truth", export_truth)
    return exported


def study(path: Path, out: Path, *extra: str) -> int:
    return cli(["study", "--profile", str(path), "--out", str(out), "--no-progress", *extra])


def results(out: Path) -> list[dict]:
    return json.loads((out / "study.json").read_text())["points"]


def test_a_material_given_another_truth_under_the_same_name_is_scored_against_it(tmp_path, fake):
    out = tmp_path / "study"
    assert study(profile(tmp_path, "virtual:gold"), out) == 0
    gold = {json.loads(p.read_text())["truth"] for p in out.glob("cells/*/result.json")}
    assert study(profile(tmp_path, "virtual:cyan"), out) == 0  # same name 'gold', another truth
    run = json.loads((out / "study.json").read_text())["run"]
    assert run["cells_run"] == run["cells_cached"] + run["cells_run"] > 0  # nothing reused
    cyan = {json.loads((out / "cells" / p["key"] / "result.json").read_text())["truth"] for p in results(out)}
    assert len(gold) == len(cyan) == 1 and gold != cyan
    assert Path(cyan.pop()).read_text() == "truth of virtual:cyan\n"
    assert fake == ["virtual:gold", "virtual:cyan"]
    for truth in (out / "truths").glob("*.onnx"):  # a deleted truth comes back the same: cells stay cached
        truth.unlink()
    assert study(profile(tmp_path, "virtual:cyan"), out) == 0
    assert json.loads((out / "study.json").read_text())["run"]["cells_run"] == 0


def test_a_damaged_cached_truth_is_exported_again(tmp_path, fake, capsys):
    out = tmp_path / "study"
    assert study(profile(tmp_path), out) == 0
    (truth,) = (out / "truths").glob("*.onnx")
    truth.write_text("truth of virt")  # cut off
    assert study(profile(tmp_path), out) == 0
    assert truth.read_text() == "truth of virtual:gold\n" and fake == ["virtual:gold"] * 2
    assert f"{truth}: does not match the SHA-256 recorded" in capsys.readouterr().err
    repaired = json.loads((out / "study.json").read_text())["health"]["repaired"]
    assert [r["file"] for r in repaired] == [str(truth.relative_to(out))]


@pytest.mark.parametrize("damage, problem", [
    (lambda text, other: text[: len(text) // 2], "not readable as JSON"),
    (lambda text, other: "[1, 2]", "holds a JSON list"),
    (lambda text, other: text.replace('"seed": 1', '"seed": "1"'), "'seed' is '1'"),
    (lambda text, other: text.replace('"failure": null', '"failure": 3'), "'failure' is 3"),
    (lambda text, other: other, "is the result of another cell (gold abc DS2 0.0 1"),
    (lambda text, other: text.replace('"key": "', '"key": "0'), "is the result of the cell with key 0"),
    (lambda text, other: text.replace('"truth_sha256": "', '"truth_sha256": "0'), "was scored against another truth than the material's now"),
])
def test_a_damaged_or_foreign_cached_result_is_said_in_one_line_and_the_cell_reruns(tmp_path, fake, capsys, damage,
                                                                                    problem):
    out, path = tmp_path / "study", profile(tmp_path)
    assert study(path, out) == 0
    cells = plan_cells(load_profile(str(path)))
    keys = {(c.plan, c.noise, c.seed): cell_key(c, load_profile(str(path))) for c in cells}
    target = out / "cells" / keys[("DS1", 0.0, 1)] / "result.json"
    other = (out / "cells" / keys[("DS2", 0.0, 1)] / "result.json").read_text()
    target.write_text(damage(target.read_text(), other))
    capsys.readouterr()
    assert study(path, out) == 0
    err = capsys.readouterr().err
    assert f"study: {target}: {problem}" in err and "; the cell runs again" in err, err
    assert len([line for line in err.splitlines() if str(target) in line]) == 1
    study_json = json.loads((out / "study.json").read_text())
    assert study_json["run"]["cells_run"] == 1 and study_json["health"]["repaired"][0]["file"].startswith("cells/")
    assert sorted((p["plan"], p["noise"], p["seed"]) for p in study_json["points"]) == sorted(keys)  # each cell once
    assert json.loads(target.read_text())["seed"] == 1


def test_what_a_killed_run_left_among_the_cells_is_cleared_and_the_cell_reruns(tmp_path, fake):
    """A cell folder without its result (a run killed while the cell was published) and the attempt
    folders of cells that were running are removed; the cell runs again and its folder is whole."""
    from neuralbrdf.atomic import TEMP_MARKER

    out, path = tmp_path / "study", profile(tmp_path)
    assert study(path, out) == 0
    keys = sorted(p.name for p in (out / "cells").iterdir())
    folder = out / "cells" / keys[0]
    (folder / "result.json").unlink()
    (folder / "stray.txt").write_text("left over")
    attempt = out / "cells" / f".{keys[1]}{TEMP_MARKER}99999999-0a1b2c3d"
    attempt.mkdir()
    (attempt / "log.txt").write_text("half a cell")
    assert study(path, out) == 0
    assert json.loads((out / "study.json").read_text())["run"]["cells_run"] == 1
    assert sorted(p.name for p in (out / "cells").iterdir()) == keys
    assert sorted(p.name for p in folder.iterdir()) == ["cell.json", "result.json"]


def test_a_cut_off_run_log_is_repaired_and_its_damaged_line_kept(tmp_path, fake, capsys):
    out, path = tmp_path / "study", profile(tmp_path)
    assert study(path, out) == 0
    log = out / "runs.jsonl"
    log.write_text(log.read_text() + '{"started": "2024-01-01T00:0')  # a run killed while appending
    assert study(path, out) == 0
    assert "runs.jsonl: line 2 is not a JSON record" in capsys.readouterr().err
    assert [json.loads(line)["cells_run"] for line in log.read_text().splitlines()] == [6, 0]
    assert (out / "runs.jsonl.damaged").read_text() == '{"started": "2024-01-01T00:0\n'
    assert study(path, out) == 0  # and the next run appends as usual
    assert len(log.read_text().splitlines()) == 3


def test_a_second_study_on_a_folder_in_use_is_refused_at_once(tmp_path, fake, capsys):
    import os

    out = tmp_path / "study"
    with folder_lock(out, "study"):
        assert study(profile(tmp_path), out) == 2
        assert sorted(p.name for p in out.iterdir()) == [".neuralbrdf.lock"] and not fake
    assert capsys.readouterr().err.strip().splitlines() == [
        f"neuralbrdf study: error: {out}: in use by another study (process {os.getpid()}); "
        "wait for it to end or choose another folder"]


def test_a_worker_still_running_its_cell_keeps_the_folder_locked(tmp_path):
    """A worker that outlives its study's own descriptor (the study process gone, the worker not yet
    ended by the parent-death signal) still holds the folder's lock: until it ends, no new study can
    clear the cell it is writing."""
    release = tmp_path / "release"
    waits = f"import os, sys, time\nsys.stdin.readline()\nwhile not os.path.exists({str(release)!r}): time.sleep(0.05)\n"
    with folder_lock(tmp_path / "study", "study") as lock:
        (tmp_path / "study" / "cells").mkdir()
        worker = workers.CellWorker((sys.executable, "-c", waits), keep_fds=(lock.fd,))
        worker._start()
        worker.process.stdin.write("cell\n")
        worker.process.stdin.flush()
    try:  # the study's own descriptor is closed: the worker still holds the lock
        with pytest.raises(InputError, match="in use by another study"):
            with folder_lock(tmp_path / "study", "study"):
                pass
    finally:
        release.touch()
        worker.close()
    with folder_lock(tmp_path / "study", "study"):
        pass


def test_crashed_and_failed_cells_make_the_study_fail_and_say_so(tmp_path, fake, capsys):
    variants = ABC + ("  - {name: crash, method: abc, config: configs/abc.yaml, speed_accuracy: false}\n"
                      "  - {name: fails, method: abc, config: configs/abc.yaml, speed_accuracy: false}\n")
    out, path = tmp_path / "study", profile(tmp_path, variants=variants)
    assert study(path, out) == 1
    err = capsys.readouterr().err
    health = json.loads((out / "study.json").read_text())["health"]
    assert health["status"] == "incomplete" and health["exit_status"] == 1
    assert [r["model"] for r in health["crashed"]] == ["crash"] and [r["model"] for r in health["failed"]] == ["fails"]
    assert health["summary"].startswith("1 of 8 cells crashed without a result: the study is incomplete")
    assert "1 of 8 cells failed" in health["summary"] and "C at its upper bound" in health["summary"]
    assert f"neuralbrdf study: error: {health['summary']}" in err
    assert study(path, out, "--allow-failures") == 1  # a crash still fails the run (and is retried)
    assert json.loads((out / "study.json").read_text())["run"]["cells_run"] == 1
    without_crash = profile(tmp_path, variants=ABC + variants.splitlines(keepends=True)[2])
    assert study(without_crash, out) == 1
    assert study(without_crash, out, "--allow-failures") == 0
    assert json.loads((out / "study.json").read_text())["health"]["status"] == "failed_cells"
    assert "neuralbrdf study: note: 1 of 7 cells failed" in capsys.readouterr().err
    assert study(profile(tmp_path), out) == 0
    assert json.loads((out / "study.json").read_text())["health"]["summary"] == "every one of the 6 cells has a model."


@pytest.mark.parametrize("change, key, message", [
    (("virtual:gold", "virtual:silver"), "materials[0].truth", "no virtual material 'silver'"),
    (("resolution: 16}\nhemisphere", "resolution: 1}\nhemisphere"), "render.resolution", "from 16 to 2048"),
    (("resolution: 16}\nhemisphere", "resolution: 100000}\nhemisphere"), "render.resolution", "from 16 to 2048"),
    (("[4, 5]", "[1000, 1000]"), "hemisphere_strata", "at most 1048576"),
    (("batch: 64", "batch: 10000000000"), "cost.batch", "from 1 to 16777216"),
    (("noise: [0.0, 0.03]", "noise: [.nan]"), "stability.noise[0]", "expected a relative noise"),
    (("seeds: [0, 1]", "seeds: [-1]"), "stability.seeds[0]", "expected an integer >= 0"),
])
def test_a_bad_profile_is_refused_naming_its_key_and_leaves_no_folder(tmp_path, fake, capsys, change, key, message):
    path = profile(tmp_path)
    path.write_text(path.read_text().replace(*change))
    out = tmp_path / "study"
    assert study(path, out) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{path}, key {key!r}:" in err and message in err, err
    assert not out.exists()


def test_a_truth_file_must_be_a_valid_ground_truth(tmp_path, fake, capsys):
    from onnx_fixtures import write_nlb_like

    table = tmp_path / "table.csv"
    assert cli(["simulate", "--material", "gold", "--truth", "--out", str(table)]) == 0
    fitted = write_nlb_like(tmp_path / "fitted.onnx")
    damaged = tmp_path / "damaged.onnx"
    damaged.write_bytes(fitted.read_bytes()[:500])
    for truth, message in ((fitted, "is a 'nlb' model; a truth is a ground truth of kind 'reference'"),
                           (damaged, "not a valid model file")):
        path = profile(tmp_path, f'{truth}", table: "{table}')
        assert study(path, tmp_path / "study") == 2
        err = capsys.readouterr().err
        assert f"key 'materials[0].truth': {message}" in err, err
    assert not (tmp_path / "study").exists()


def test_an_output_folder_that_is_a_file_is_one_line(tmp_path, fake, capsys):
    out = tmp_path / "taken"
    out.write_text("mine")
    assert study(profile(tmp_path), out) == 2
    assert capsys.readouterr().err == f"neuralbrdf study: error: {out}: exists and is not a folder\n"
    assert out.read_text() == "mine"


# --------------------------------------------------------------------------- seeds


def test_seeds_run_only_where_they_change_the_fit(tmp_path):
    """A noise-free NLB cell runs at seed 0 only (its fit is deterministic); ABC passes the seed to its
    random starts; every method keeps its seeds where noise is drawn; study.json says which is which."""
    from neuralbrdf.study.cells import seed_args, seeding_description

    path = profile(tmp_path, variants=ABC + "  - {name: nlb, method: nlb, config: configs/nlb_latent.yaml, "
                                            "group: latent, label: default}\n")
    path.write_text(path.read_text().replace("variants: [abc]", "variants: [abc, nlb]"))
    cells = plan_cells(load_profile(str(path)))
    seeds = {(c.variant, c.plan, c.noise): sorted(x.seed for x in cells if (x.variant, x.plan, x.noise) ==
                                                  (c.variant, c.plan, c.noise)) for c in cells}
    assert seeds[("nlb", "DS1", 0.0)] == seeds[("nlb", "DS2", 0.0)] == [MAIN_SEED]
    assert seeds[("nlb", "DS1", 0.03)] == seeds[("abc", "DS1", 0.0)] == seeds[("abc", "DS2", 0.0)] == [0, 1]
    assert seed_args("abc", 3) == ["--model.seed", "3"] and seed_args("nlb", 3) == seed_args("spectral_mlp", 3) == []
    assert "seed 0 only" in seeding_description("nlb") and "random starts" in seeding_description("abc")
    assert "seed 0 only" in seeding_description("nlb_spectral") and "seed 0" not in seeding_description("spectral_mlp")


def test_the_cell_passes_its_seed_to_the_abc_starts_and_they_differ():
    from neuralbrdf.fitting.abc_fit import AbcBounds, _start_shapes
    from neuralbrdf.study.cell import fit_arguments

    spec = {"variant": {"config": "abc.yaml", "args": [], "method": "abc"}, "material": {},
            "cell": {"seed": 3}}
    args = fit_arguments(spec, Path("t.csv"), Path("run"))
    assert args[args.index("--model.seed") + 1] == "3" and args[args.index("--seed_everything") + 1] == "3"
    assert _start_shapes(AbcBounds(), 4, 0)[1:] != _start_shapes(AbcBounds(), 4, 3)[1:]


def test_a_typo_in_a_variants_arguments_is_a_refused_fit_in_one_line(tmp_path):
    from neuralbrdf.study.cell import CellFailure, fit

    from neuralbrdf.configs_dir import resolve_config

    spec = {"variant": {"config": str(resolve_config("abc")), "args": ["--model.n_startz", "1"], "method": "abc"},
            "material": {}, "cell": {"seed": 0}}
    with pytest.raises(CellFailure) as failure:
        fit(spec, tmp_path / "table.csv", tmp_path / "run")
    assert failure.value.cause == "fit_refused"
    message = str(failure.value)
    assert "\n" not in message and "'n_startz'" in message and "did you mean n_starts?" in message, message


@pytest.mark.slow
@pytest.mark.parametrize("config", ["nlb_latent", "nlb_spectral"])
def test_two_seeds_of_a_noise_free_nlb_fit_are_the_same_fit(tmp_path, config):
    """Why noise-free NLB cells run one seed: with another --seed_everything the latent fit is the same
    (the spectral fit on a spectral DS1 table also draws subsets of samples, from its data.seed)."""
    import torch

    from neuralbrdf.checkpoints import read_checkpoint
    from neuralbrdf.lightning.run import main as train

    table = tmp_path / "gold.csv"
    assert cli(["sample", "virtual:gold", "--plan", "DS1", "--out", str(table)]) == 0
    fitted = []
    for seed in (0, 3):
        run = tmp_path / f"run{seed}"
        assert train(["fit", "--config", config, "--data.path", str(table), "--run_dir", str(run),
                      "--seed_everything", str(seed), "--trainer.max_epochs", "1", "--data.steps_per_epoch", "20",
                      "--trainer.enable_progress_bar", "false"]) == 0
        fitted.append(read_checkpoint(run / "checkpoints" / "fitted.ckpt")["state_dict"])
    assert fitted[0].keys() == fitted[1].keys() and all(torch.equal(fitted[0][k], fitted[1][k]) for k in fitted[0])


# --------------------------------------------------------------------------- a killed study


STUDY_DRIVER = r"""
import sys
from pathlib import Path

from neuralbrdf.evaluation import truth
from neuralbrdf.study import workers

def export_truth(source, out):
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(f"truth of {source}\n")

truth.export_truth = export_truth
workers.WORKER_COMMAND = (sys.executable, "-c", sys.argv[1])  # the real worker loop, a cell that never ends
from neuralbrdf.cli.main import main
sys.exit(main(sys.argv[2:]))
"""

ENDLESS_CELL_WORKER = r"""
import os, time
from pathlib import Path
from neuralbrdf.study import cell

def endless_cell(folder):
    Path(MARKER).write_text(str(os.getpid()))
    while True:
        time.sleep(1)

cell._import_fitting = lambda: None
cell._run_logged = endless_cell
cell.serve()
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc")
def test_a_killed_studys_workers_end_with_it(tmp_path):
    """SIGKILL of the study: its cell worker went on with its cell (writing result.json seconds later)
    and held the folder, so a rerun raced a ghost or was refused; it now ends within a moment."""
    import os
    import signal
    import subprocess
    import time

    from process_hooks import is_alive

    marker, out = tmp_path / "cell-started", tmp_path / "study"
    worker_code = ENDLESS_CELL_WORKER.replace("MARKER", repr(str(marker)))
    with open(tmp_path / "log.txt", "w") as log:
        study_process = subprocess.Popen(
            [sys.executable, "-c", STUDY_DRIVER, worker_code, "study", "--profile", str(profile(tmp_path)),
             "--out", str(out), "--no-progress"], stdout=log, stderr=subprocess.STDOUT)
    worker = None
    try:
        deadline = time.monotonic() + 120
        while not (marker.is_file() and marker.read_text()):
            assert study_process.poll() is None and time.monotonic() < deadline, (tmp_path / "log.txt").read_text()
            time.sleep(0.05)
        worker = int(marker.read_text())
        study_process.send_signal(signal.SIGKILL)
        study_process.wait()
        ended = time.monotonic() + 10
        while is_alive(worker) and time.monotonic() < ended:
            time.sleep(0.05)
        assert not is_alive(worker), "the cell worker outlived its study"
        with folder_lock(out, "study"):  # and the folder is free for a rerun
            pass
    finally:
        if study_process.poll() is None:
            study_process.kill()
        if worker is not None and is_alive(worker):
            os.kill(worker, signal.SIGKILL)
