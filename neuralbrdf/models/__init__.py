"""BRDF models as plain ``nn.Module``\\ s (docs/models.md): the spectral MLP (:mod:`~neuralbrdf.models.spectral_mlp`),
the NLB network (:mod:`~neuralbrdf.models.nlb`) and every model on directions
(:mod:`~neuralbrdf.models.directional`); the ABC formula is :mod:`neuralbrdf.physics.abc`."""
