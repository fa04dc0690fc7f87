"""Train, validate or test a BRDF model from a YAML config: ``python train.py fit --config configs/X.yaml``.

A thin entry to :func:`neuralbrdf.lightning.run.main` (LightningCLI); see that module for the
run directory layout, and ``python train.py fit --help`` for every option.
"""

import sys

from neuralbrdf.lightning.run import main

if __name__ == "__main__":
    sys.exit(main())
