"""``neuralbrdf view``: an interactive BRDF explorer in the browser for model files, a truth and
the measurement they came from.

A local web server (:mod:`~neuralbrdf.explorer.server`) evaluates the models with onnxruntime
(:mod:`~neuralbrdf.explorer.models`) on the direction grids of each view (:mod:`~neuralbrdf.explorer.grids`)
and serves one page that draws them with plotly.js (:mod:`~neuralbrdf.explorer.views` lists the views).
:func:`neuralbrdf.explorer.launch.open_scene` checks and opens the files;
:class:`~neuralbrdf.explorer.server.Viewer` serves them; :func:`neuralbrdf.api.view` opens and serves them
(the command line, :mod:`neuralbrdf.cli.view_command`, calls it).  This package's ``__init__`` imports nothing, so that the command line starts fast.
"""
