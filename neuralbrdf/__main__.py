"""``python -m neuralbrdf`` runs the command line."""

import sys

from neuralbrdf.cli.main import main

sys.exit(main())
