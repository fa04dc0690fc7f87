"""Import the scripts under ``export/`` (not a package: nothing under neuralbrdf/ imports them)."""

import importlib.util
import sys
from pathlib import Path

EXPORT_DIR = Path(__file__).resolve().parents[1] / "export"


def load_export_script(stem: str):
    """The module ``export/<stem>.py``, registered as ``export_<stem>_under_test``."""
    name = f"export_{stem}_under_test"
    spec = importlib.util.spec_from_file_location(name, EXPORT_DIR / f"{stem}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
