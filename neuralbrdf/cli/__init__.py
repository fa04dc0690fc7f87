"""Command-line interface (``neuralbrdf`` console script)."""
