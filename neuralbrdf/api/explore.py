"""Exploring: :func:`view` models, a truth and a measurement in the interactive BRDF explorer."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from neuralbrdf.api.arguments import PathLike, check_integers, check_text
from neuralbrdf.api.materials import Source, read
from neuralbrdf.api.model_files import Model, model_path
from neuralbrdf.errors import InputError

if TYPE_CHECKING:
    from neuralbrdf.data.table import BrdfTable


def view(*models: Model | PathLike, truth: Model | PathLike | None = None,
         table: Source | BrdfTable | PathLike | None = None, reference: PathLike | None = None,
         host: str = "127.0.0.1", port: int = 0, start: bool = True):
    """Serve the interactive BRDF explorer of ``neuralbrdf view`` for ``models`` (model files, any
    kind), a ``truth`` (kind ``reference``) and a measurement ``table`` (a :class:`Source`, a table,
    or what :func:`read` takes, with its ``reference`` for a GCMS raw file) in a background thread
    and return the running :class:`~neuralbrdf.explorer.server.Viewer`: open ``viewer.url`` in a
    browser, ``viewer.stop()`` ends it (or use it in a ``with`` block).  ``host`` ``127.0.0.1``:
    this machine only; ``port`` 0: a free one.  ``start=False``: the viewer bound but not serving
    yet (``viewer.serve_forever()`` serves in the calling thread, as ``neuralbrdf view`` does).

    >>> import json, tempfile, urllib.request, neuralbrdf as nb
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     gold = nb.truth("virtual:gold", f"{folder}/gold.onnx")
    ...     with nb.view(gold, table="virtual:gold") as viewer:
    ...         scene = json.load(urllib.request.urlopen(viewer.url + "api/scene"))
    >>> viewer.url  # doctest: +ELLIPSIS
    'http://127.0.0.1:.../'
    >>> [source["kind"] for source in scene["sources"]], scene["measured"]["rows"]
    (['reference'], 1001)
    """
    from neuralbrdf.data.table import BrdfTable as Table
    from neuralbrdf.explorer.launch import open_scene
    from neuralbrdf.explorer.server import Viewer

    check_text("host", host, optional=False)
    check_integers(port=port)
    label = None
    if table is not None and not isinstance(table, (Source, Table)):
        from neuralbrdf.data.units import overridden_by

        label = os.fspath(table)
        with overridden_by("nb.view(..., table=nb.read(TABLE, trust_units=True))"):
            table = read(table, reference)
    elif reference is not None:
        raise InputError("a Munsell reference goes with a GCMS raw table file")
    if isinstance(table, Source):
        label = label or table.location
        table = table.samples
    scene = open_scene([model_path(m, f"models[{i}]") for i, m in enumerate(models)],
                       None if truth is None else model_path(truth, "truth"), table, label)
    viewer = Viewer(scene, host, port)
    return viewer.start() if start else viewer
