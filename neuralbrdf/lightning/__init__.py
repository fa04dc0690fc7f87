"""PyTorch Lightning layer: data modules, training modules and the ``train.py`` command line.

Models themselves are plain :class:`torch.nn.Module` classes in :mod:`neuralbrdf.models`;
losses and metrics are pure functions in :mod:`neuralbrdf.losses` and :mod:`neuralbrdf.metrics`.
"""
