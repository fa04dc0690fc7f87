"""Export a trained checkpoint to the self-contained ONNX file of docs/formats.md#onnx-model-files.

    python export/to_onnx.py --ckpt RUN.ckpt --out MODEL.onnx [--material NAME]

The same command as ``neuralbrdf export`` (:mod:`neuralbrdf.cli.export_command`).
"""

import sys

from neuralbrdf.cli.export_command import main

if __name__ == "__main__":
    sys.exit(main(prog="export/to_onnx.py"))
