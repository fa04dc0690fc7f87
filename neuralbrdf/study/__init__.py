"""The study (docs/study.md): every model variant × material × plan × noise × seed, cached, charted as
error against cost with Pareto fronts, stability box plots and a failure map, reported as a static
``index.html`` with ``study.json``.  Entry: ``neuralbrdf study`` (:mod:`neuralbrdf.study.command`)."""
