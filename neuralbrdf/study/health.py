"""Whether a study run produced what it claims (``study.json``'s ``health``; the exit status).

A study's failure map (docs/study.md) is evidence: a fit that breaks on a sparse plan or under noise
is a result.  What is not evidence:

* a **crashed** cell (``cell_crashed``): its process died or raised without writing a result — a
  bug, a full disk, a damaged input.  The study is *incomplete*; a rerun retries the cell.
* a **failed** cell: a fit that ended without a model or an export or evaluation that was
  refused (:data:`CELL_FAILURES`).  Its model is missing from every chart.

``neuralbrdf study`` exits with status 1 when a cell crashed, and when a cell failed unless
``--allow-failures`` says failed fits are expected (a stability sweep on sparse plans); the error
above twice the DS1 error is a measurement and never fails the run.  ``health`` records the
cells of each kind, the cached files that were repaired, and a ``summary`` for the top of the
report.
"""

from __future__ import annotations

from collections import Counter

#: Failure causes that mean a cell has no usable model (:mod:`neuralbrdf.study.cell`).
CELL_FAILURES = ("non_finite_loss", "optimizer_failure", "fit_refused", "export_refused", "evaluation_error")
CRASHED = "cell_crashed"
#: ``health.status``: every cell gave a model / some cells failed / some cells have no result.
COMPLETE, FAILED_CELLS, INCOMPLETE = "complete", "failed_cells", "incomplete"


def _row(point: dict) -> dict:
    return {"key": point.get("key"), "material": point["material"], "model": point["model"], "plan": point["plan"],
            "noise": point["noise"], "seed": point["seed"], "cause": point["failure"], "message": point["message"]}


def _described(rows: list[dict], what: str, total: int) -> str:
    causes = Counter(row["cause"] for row in rows)
    first = rows[0]
    noise = f" {first['noise'] * 100:g}% noise" if first["noise"] else ""
    return (f"{len(rows)} of {total} cells {what} ({', '.join(f'{c} ×{n}' for c, n in causes.items())}); first: "
            f"{first['model']} on {first['material']} {first['plan']}{noise} seed {first['seed']}: {first['message']}")


def health(points: list[dict], repaired: list[dict], allow_failures: bool) -> dict:
    """``study.json``'s ``health`` (module docstring) of the study's points."""
    crashed = [_row(p) for p in points if p["failure"] == CRASHED]
    failed = [_row(p) for p in points if p["failure"] in CELL_FAILURES]
    status = INCOMPLETE if crashed else FAILED_CELLS if failed else COMPLETE
    parts = []
    if crashed:
        parts.append(_described(crashed, "crashed without a result: the study is incomplete (a rerun retries them)",
                                len(points)))
    if failed:
        parts.append(_described(failed, "failed: their models are in no chart", len(points)))
    if repaired:
        parts.append(f"{len(repaired)} cached files were damaged or stale and were redone (first: "
                     f"{repaired[0]['file']}: {repaired[0]['problem']})")
    return {"status": status, "exit_status": exit_status(status, allow_failures), "allow_failures": allow_failures,
            "crashed": crashed, "failed": failed, "repaired": repaired,
            "summary": ". ".join(parts) + "." if parts else f"every one of the {len(points)} cells has a model."}


def exit_status(status: str, allow_failures: bool) -> int:
    """``neuralbrdf study``'s exit status for a ``health.status`` (module docstring)."""
    return 0 if status == COMPLETE or (status == FAILED_CELLS and allow_failures) else 1
