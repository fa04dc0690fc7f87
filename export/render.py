"""Render an exported model, or any scene that uses it, with Mitsuba 3 (docs/mitsuba-plugin.md).

    python export/render.py --model MODEL.onnx --out IMAGE.png [--variant llvm_ad_spectral] ...
    python export/render.py --scene SCENE.xml --out IMAGE.png ...

The same command as ``neuralbrdf render`` (:mod:`neuralbrdf.cli.render_command`).
"""

import sys

from neuralbrdf.cli.render_command import main

if __name__ == "__main__":
    sys.exit(main(prog="export/render.py"))
