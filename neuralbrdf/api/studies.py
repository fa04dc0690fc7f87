"""The study (docs/study.md): :func:`study` runs every model variant of a profile on its materials,
plans, noise levels and seeds, cached, and reports it; :func:`study_report` draws the report again."""

from __future__ import annotations

import os
from pathlib import Path

from neuralbrdf.api.arguments import PathLike, as_path, check_integers
from neuralbrdf.errors import InputError


def study(profile: PathLike, out: PathLike, *, jobs: int | None = None, cluster: str | None = None,
          allow_failures: bool = False, progress: bool = False, command: str | None = None) -> dict:
    """Run (or resume) the study of ``profile`` (a shipped profile, ``quick``, ``full``, ``spectral``,
    ``latent_prior``, or a YAML file) into the folder ``out``: ``study.json``, ``figures/*.png`` and
    ``index.html``, finished cells cached under ``cells/``.  The cells run ``jobs`` at a time on
    this machine (default 1), or with ``cluster`` (``tcp://HOST:PORT``) as tasks on that Dask
    scheduler's workers (``jobs`` then not given).  ``allow_failures``: failed fits do not fail the
    study's health; ``command``: how to rerun it, recorded in the report.  Returns the content of
    ``study.json`` (its ``health`` says whether every cell gave a model)."""
    from neuralbrdf.study.runner import run_study

    check_integers(jobs=jobs)
    if jobs is not None and jobs < 1:
        raise InputError(f"must be >= 1, got {jobs}", key="jobs")
    if cluster is not None and jobs is not None:
        raise InputError("is for a study on this machine; on a cluster, the threads of the cluster's workers say how "
                         "many cells run at once", key="jobs")
    return run_study(os.fspath(as_path(profile, "profile", "a profile name or a YAML file")),
                     as_path(out, "out", "a folder path"), jobs or 1, command=command, progress=progress,
                     allow_failures=allow_failures, cluster=cluster)


def study_report(out: PathLike) -> Path:
    """Draw the figures and ``index.html`` of the study in ``out`` again from its ``study.json`` (no
    cell runs); returns the path of ``index.html``."""
    from neuralbrdf.study.report import rebuild

    return rebuild(as_path(out, "out", "a folder path"))
