"""What a study folder keeps between runs, checked before it is reused (docs/study.md, docs/robustness.md).

* **Truths** — ``truths/NAME-HASH.onnx``: a material's truth exported once, named by what it is
  made from (``HASH`` covers the truth's source — ``virtual:NAME`` or the contents of the NBRDF
  file — and :data:`TRUTH_FORMAT`), so a profile that gives a material another truth under the
  same name gets a new file, never the old one.  Beside it ``NAME-HASH.sha256`` records the
  file's SHA-256 when it was written; a file that no longer matches (damaged, cut off, edited)
  is exported again.  A truth given as ``.onnx`` (a reference model) or ``.bsdf`` (an RGL
  measurement, scored and rendered through Mitsuba's ``measured`` plugin) is used where it is.
* **Cell results** — ``cells/KEY/result.json`` is reused only when it is a JSON object of the
  expected fields and types that belongs to its cell: the same material, variant, plan, noise
  and seed, and, where it records them, the same key and truth (its SHA-256).  Anything else is
  reported in one line and the cell runs again.
* **Run log** — ``runs.jsonl``, one JSON object per run of the study.  A line that is not one (a
  run killed while appending) is moved to ``runs.jsonl.damaged`` and the log rewritten whole.

Each repair is noted (:class:`Repairs`) and listed in ``study.json`` (``health.repaired``).
"""

from __future__ import annotations

import hashlib
import json
import math
import sys
from pathlib import Path

from neuralbrdf.atomic import atomic_write
from neuralbrdf.study.cells import Cell, file_digest
from neuralbrdf.study.profile import MaterialSpec

#: Bump when exported truths change: every truth is exported again (and its cells rerun).
TRUTH_FORMAT = 1
#: The run log of a study folder.
RUNS_LOG = "runs.jsonl"
#: Where lines of the run log that are not JSON records are kept.
DAMAGED_RUNS_LOG = "runs.jsonl.damaged"
#: Fields of a cell result and their JSON types (``None`` allowed where listed).
RESULT_FIELDS = {"material": (str,), "variant": (str,), "plan": (str,), "noise": (int, float), "seed": (int,),
                 "is_main": (bool,), "failure": (str, type(None)), "message": (str, type(None)),
                 "cost": (dict,), "error": (dict,)}


class Repairs:
    """The cached files a study run found damaged or stale and redid: ``{"file", "problem"}`` each,
    each also said in one line on stderr as it is found."""

    def __init__(self, root: Path, say=None) -> None:
        self.root = root
        self.entries: list[dict] = []
        self.say = say or (lambda line: print(line, file=sys.stderr))

    def note(self, path: Path, problem: str) -> None:
        shown = str(path.relative_to(self.root)) if path.is_relative_to(self.root) else str(path)
        self.entries.append({"file": shown, "problem": problem})
        self.say(f"study: {self.root / shown}: {problem}")


def sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def truth_file(material: MaterialSpec, out_dir: Path, repairs: Repairs) -> tuple[Path, str]:
    """The material's truth file and its SHA-256 (module docstring), exported when missing or damaged."""
    from neuralbrdf.evaluation.truth import export_truth

    if not material.is_virtual and Path(material.truth).suffix in (".onnx", ".bsdf"):  # a truth file as it is
        return Path(material.truth), sha256(Path(material.truth))
    source = hashlib.sha256(f"{TRUTH_FORMAT}:{file_digest(material.truth)}".encode()).hexdigest()[:12]
    path = out_dir / "truths" / f"{material.name}-{source}.onnx"
    record = path.with_suffix(".sha256")
    if path.is_file():
        recorded = record.read_text(encoding="ascii", errors="replace").strip() if record.is_file() else None
        actual = sha256(path)
        if recorded == actual:
            return path, actual
        repairs.note(path, "does not match the SHA-256 recorded when it was exported (damaged or edited); "
                           "exported again" if recorded else "has no record of its SHA-256 (its export was "
                           "cut off?); exported again")
    export_truth(material.truth, path)
    actual = sha256(path)
    with atomic_write(record, encoding="ascii") as handle:
        handle.write(actual + "\n")
    return path, actual


def _problem(result, cell: Cell, key: str, truth_sha256: str) -> str | None:
    """Why ``result`` (parsed ``result.json``) cannot stand for ``cell``; ``None`` when it can."""
    if not isinstance(result, dict):
        return f"holds a JSON {type(result).__name__}, not a cell result"
    for name, types in RESULT_FIELDS.items():
        if name not in result:
            return f"has no {name!r}"
        value = result[name]
        if not isinstance(value, types) or (bool in types) != isinstance(value, bool):
            return f"{name!r} is {value!r}; expected {' or '.join(t.__name__ for t in types)}"
    if isinstance(result["noise"], float) and not math.isfinite(result["noise"]):
        return f"'noise' is {result['noise']!r}"
    found = (result["material"], result["variant"], result["plan"], float(result["noise"]), result["seed"])
    expected = (cell.material, cell.variant, cell.plan, cell.noise, cell.seed)
    if found != expected:
        return f"is the result of another cell ({' '.join(map(str, found))}, not {' '.join(map(str, expected))})"
    if result.get("key", key) != key:
        return f"is the result of the cell with key {result['key']}"
    if result.get("truth_sha256", truth_sha256) != truth_sha256:
        return "was scored against another truth than the material's now"
    return None


def cached_result(folder: Path, cell: Cell, key: str, truth_sha256: str, repairs: Repairs) -> dict | None:
    """``folder/result.json`` when it is a finished result of ``cell`` (module docstring), else
    ``None`` (the cell must run; a file that was there is noted in ``repairs``)."""
    path = folder / "result.json"
    if not path.is_file():
        return None
    try:
        result = json.loads(path.read_text(encoding="utf-8"))
        problem = _problem(result, cell, key, truth_sha256)
    except (OSError, UnicodeDecodeError, ValueError) as error:
        problem = f"not readable as JSON ({error})"
    if problem is None:
        return result
    repairs.note(path, f"{problem}; the cell runs again")
    return None


def read_runs(out_dir: Path, repairs: Repairs) -> list[dict]:
    """The runs recorded in ``out_dir/runs.jsonl``; damaged lines are set aside (module docstring)."""
    log = out_dir / RUNS_LOG
    if not log.is_file():
        return []
    runs, damaged = [], []
    for number, line in enumerate(log.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line)
        except ValueError:
            entry = None
        if isinstance(entry, dict):
            runs.append(entry)
        else:
            damaged.append((number, line))
    if damaged:
        kept = out_dir / DAMAGED_RUNS_LOG
        earlier = kept.read_text(encoding="utf-8", errors="replace") if kept.is_file() else ""
        with atomic_write(kept, encoding="utf-8") as handle:
            handle.write(earlier + "".join(line + "\n" for _, line in damaged))
        write_runs(out_dir, runs)
        lines = ", ".join(str(number) for number, _ in damaged)
        repairs.note(log, f"line {lines} is not a JSON record (a run cut off while writing it?); moved to "
                          f"{DAMAGED_RUNS_LOG}")
    return runs


def write_runs(out_dir: Path, runs: list[dict]) -> None:
    """``out_dir/runs.jsonl``, one line per run, written whole."""
    with atomic_write(out_dir / RUNS_LOG, encoding="utf-8") as handle:
        handle.writelines(json.dumps(entry, allow_nan=False) + "\n" for entry in runs)
