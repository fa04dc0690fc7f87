"""The study (docs/study.md): every model variant × material × plan × noise × seed, cached, charted as
error against cost with Pareto fronts, stability box plots and a failure map, reported as a static
``index.html`` with ``study.json``.  Entry: :func:`neuralbrdf.api.study`, and ``neuralbrdf study``
(:mod:`neuralbrdf.cli.study_command`) over it."""
