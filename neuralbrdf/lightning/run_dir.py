"""A training run's directory: a fresh one when nothing names it (:func:`fresh_run_dir`), what the run
it holds is (:func:`held_run`), and the directory through interruptions: a run is replaced whole or
not at all, and what a killed command leaves behind is put right by the next command in the directory.

A command in a run directory ``R`` holds its lock from start to end
(:func:`~neuralbrdf.folder_lock.folder_lock`), so anything this module finds there that another
process made was left by a process that ended without finishing (killed, crashed, out of
memory).  The folders and files it uses are named ``neuralbrdf-tmp-<pid>-<role>`` after
:data:`~neuralbrdf.atomic.TEMP_MARKER`:

* ``new-run/`` — ``fit --overwrite`` writes its run here (:func:`staging_dir`); ``R`` keeps the
  old run until the new one is whole.  Left by a killed fit, it is removed: the old run stays.
* ``finished-run/``, ``old-run/``, ``discard/`` — :func:`swap_in` puts a finished new run in
  place of the old one: the staging folder is renamed ``finished-run`` (the new run is whole),
  the old run's entries move into ``old-run`` which is then renamed ``discard`` (the old run is
  out), the new entries move into ``R``, and ``discard`` is deleted.  A swap cut short is
  completed from the step it reached, so ``R`` always ends with the new run whole.
* ``replaced-run/`` — left by older versions, which set the old run aside there and wrote the
  new one into ``R``: the old run is put back and the half-written one removed.
* ``earlier-metrics.csv`` — the log of the sessions before a ``fit --resume``
  (:func:`set_aside_log`), joined in front of the resumed session's log when it ends
  (:func:`join_logs`), or by the next command if it was killed.

:func:`recover` does all of that (and removes the temporary files of dead processes that
:mod:`neuralbrdf.atomic` leaves beside checkpoints and logs) and says what it did.
"""

from __future__ import annotations

import csv
import json
import os
import re
import shutil
from datetime import datetime
from pathlib import Path

from neuralbrdf.atomic import TEMP_MARKER, atomic_write, remove_stale_temporaries
from neuralbrdf.folder_lock import outermost_missing
from neuralbrdf.lightning.metrics_json import (METRICS_FILE, STATUS_ENVIRONMENT, STATUS_FAILED, STATUS_INTERRUPTED,
                                               STATUS_OK, STATUS_RUNNING)

#: Where a run goes when nothing names its directory: ``runs/<config stem>/<timestamp>`` (:func:`fresh_run_dir`).
RUNS_ROOT = Path("runs")
#: What a run writes into its directory; a directory holding any of these holds a run.
RUN_ENTRIES = ("metrics.json", "metrics.csv", "config.yaml", "hparams.yaml", "checkpoints", "validate", "test")
#: Prefix of every leftover of this module: ``neuralbrdf-tmp-<pid>-<role>``.
LEFTOVER_PREFIX = TEMP_MARKER.lstrip(".")
NEW_RUN, FINISHED_RUN, OLD_RUN, DISCARD, REPLACED_RUN = "new-run", "finished-run", "old-run", "discard", "replaced-run"
EARLIER_LOG = "earlier-metrics.csv"
_LEFTOVER = re.compile(re.escape(LEFTOVER_PREFIX) + r"(\d+)-(.+)")
#: Sub-folders of a run where :mod:`neuralbrdf.atomic` writes temporary files.
_WRITTEN_FOLDERS = (".", "checkpoints", "validate", "test")


def leftover(run_dir: Path, role: str, pid: int | None = None) -> Path:
    """``run_dir/neuralbrdf-tmp-<pid>-<role>`` (this process's by default)."""
    return Path(run_dir) / f"{LEFTOVER_PREFIX}{os.getpid() if pid is None else pid}-{role}"


def staging_dir(run_dir: Path) -> Path:
    """The folder a ``fit --overwrite`` of this process writes its run into (module docstring)."""
    return leftover(run_dir, NEW_RUN)


def holds_run(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds the files of a run (:data:`RUN_ENTRIES`)."""
    return any((Path(run_dir) / entry).exists() for entry in RUN_ENTRIES)


def run_entries(run_dir: Path) -> list[str]:
    """The :data:`RUN_ENTRIES` present in ``run_dir`` (folders with a trailing ``/``)."""
    run_dir = Path(run_dir)
    return [f"{entry}/" if (run_dir / entry).is_dir() else entry for entry in RUN_ENTRIES
            if (run_dir / entry).exists() or (run_dir / entry).is_symlink()]


def remove_entry(path: Path) -> None:
    """Delete a run entry, a folder with what it holds."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _move_entries(source: Path, target: Path, replace: bool = False) -> None:
    """Move the :data:`RUN_ENTRIES` of ``source`` into ``target`` (an entry ``target`` already holds
    is kept unless ``replace``)."""
    for entry in RUN_ENTRIES:
        old = source / entry
        if not (old.exists() or old.is_symlink()):
            continue
        new = target / entry
        if new.exists() or new.is_symlink():
            if not replace:
                continue
            remove_entry(new)
        os.replace(old, new)


def swap_in(run_dir: Path, staging: Path) -> None:
    """Put the whole run in ``staging`` (a ``new-run`` or ``finished-run`` folder of ``run_dir``) in
    place of the run in ``run_dir``, resumably (module docstring)."""
    pid = _LEFTOVER.fullmatch(staging.name).group(1)
    finished, old, discard = (leftover(run_dir, role, int(pid)) for role in (FINISHED_RUN, OLD_RUN, DISCARD))
    if staging != finished:
        os.replace(staging, finished)
    if not discard.exists():  # the old run is not yet wholly out of the way
        old.mkdir(exist_ok=True)
        _move_entries(run_dir, old)
        os.replace(old, discard)
    _move_entries(finished, run_dir, replace=True)
    shutil.rmtree(finished)
    shutil.rmtree(discard)


def _put_back(run_dir: Path, replaced: Path) -> None:
    """An older version's ``replaced-run``: the old run back, the half-written new one (every run
    entry of ``run_dir``: the old ones were all set aside) removed."""
    for entry in RUN_ENTRIES:
        remove_entry(run_dir / entry)
    _move_entries(replaced, run_dir)
    shutil.rmtree(replaced)


# --------------------------------------------------------------------------- a resumed run's log


def _read_log(path: Path) -> tuple[list[str], list[dict]]:
    """Header and rows of a CSV log (empty if missing or unreadable)."""
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            reader = csv.DictReader(handle)
            rows = list(reader)
            return list(reader.fieldnames or []), rows
    except (OSError, UnicodeDecodeError, csv.Error):
        return [], []


def set_aside_log(run_dir: Path) -> Path | None:
    """Move ``metrics.csv`` of a run about to be resumed aside (Lightning's logger starts a new
    file); ``None`` when there is none.  :func:`join_logs` joins them again."""
    log = Path(run_dir) / "metrics.csv"
    if not log.is_file():
        return None
    earlier = leftover(run_dir, EARLIER_LOG)
    os.replace(log, earlier)
    return earlier


def join_logs(run_dir: Path, earlier: Path) -> None:
    """``metrics.csv`` of ``run_dir``: the rows of ``earlier`` (the sessions before a resume), then its
    own; ``earlier`` is removed."""
    log = Path(run_dir) / "metrics.csv"
    if not log.is_file():
        os.replace(earlier, log)
        return
    header, rows = _read_log(earlier)
    new_header, new_rows = _read_log(log)
    fields = [*header, *(name for name in new_header if name not in header)]
    with atomic_write(log) as handle:
        writer = csv.DictWriter(handle, fieldnames=fields, restval="")
        writer.writeheader()
        writer.writerows([*rows, *new_rows])
    earlier.unlink()


# --------------------------------------------------------------------------- recovery


def recover(run_dir: Path) -> list[str]:
    """Put ``run_dir`` right after commands that ended in it without finishing (module docstring);
    call it holding the directory's lock.  Returns one sentence per repair, for the user."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        return []
    notes = []
    # a finished run first: completing its swap decides what its old-run and discard folders hold
    order = (FINISHED_RUN, NEW_RUN, REPLACED_RUN, EARLIER_LOG, OLD_RUN, DISCARD)
    found = sorted(((int(match.group(1)), order.index(match.group(2)) if match.group(2) in order else len(order)),
                    match.group(2), path) for path in run_dir.iterdir()
                   if (match := _LEFTOVER.fullmatch(path.name)) and int(match.group(1)) != os.getpid())
    for (pid, _), role, path in found:
        if not (path.exists() or path.is_symlink()):
            continue  # handled with another leftover of the same process
        if role == NEW_RUN:
            shutil.rmtree(path)
            notes.append(f"removed the unfinished run of process {pid} (a fit --overwrite that ended before its run "
                         "was whole); the run it was to replace is kept")
        elif role == FINISHED_RUN:
            swap_in(run_dir, path)
            notes.append(f"put in place the finished run of process {pid}, which ended while replacing the run")
        elif role in (OLD_RUN, DISCARD):  # no finished run of its process is left to swap in: it is out
            shutil.rmtree(path)
        elif role == REPLACED_RUN:
            _put_back(run_dir, path)
            notes.append(f"put back the run that process {pid} was replacing when it ended (the half-written new "
                         "run is removed)")
        elif role == EARLIER_LOG:
            join_logs(run_dir, path)
            notes.append(f"joined the log of the sessions before the resume of process {pid}, which ended, to "
                         "metrics.csv")
    for folder in _WRITTEN_FOLDERS:
        for entry in list((run_dir / folder).glob(f".*{TEMP_MARKER}*")) if (run_dir / folder).is_dir() else []:
            target = entry.with_name(entry.name[1:].split(TEMP_MARKER, 1)[0])
            remove_stale_temporaries(target)
    return notes


def fresh_run_dir(config_paths) -> tuple[Path, Path]:
    """A new folder ``runs/<config stem>/<timestamp>[-N]``, created here (two commands started in the
    same second get two folders), and the outermost folder created for it."""
    stem = Path(str(config_paths[-1])).stem if config_paths else "run"
    base = RUNS_ROOT / stem / datetime.now().strftime("%Y%m%d-%H%M%S")
    candidate, suffix = base, 0
    while True:
        created = outermost_missing(candidate)
        try:
            candidate.mkdir(parents=True)
            return candidate, created or candidate
        except FileExistsError:
            suffix += 1
            candidate = base.with_name(f"{base.name}-{suffix}")


def held_run(run_dir: Path) -> str:
    """What the run in ``run_dir`` holds, for the refusal of a fit that would replace it."""
    listing = ", ".join(run_entries(run_dir))
    try:
        status = json.loads((run_dir / METRICS_FILE).read_text(encoding="utf-8")).get("status")
    except (OSError, ValueError, AttributeError):
        status = None
    if status in (STATUS_OK, STATUS_FAILED):
        return f"already holds a run ({listing})"
    why = {STATUS_RUNNING: f"its {METRICS_FILE} says it is still running, but no command runs in it: it was killed",
           STATUS_INTERRUPTED: "it was interrupted",
           STATUS_ENVIRONMENT: f"the machine stopped it (its {METRICS_FILE} says why)"}.get(
        status, f"no {METRICS_FILE}: it ended before its fit did, or was killed")
    return f"already holds a run that did not finish ({listing}; {why})"
