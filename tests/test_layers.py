"""The package's import rules are import-linter contracts in pyproject.toml (``[tool.importlinter]``,
docs/architecture.md): its floors import only the floors below them, the modules of each package
import one another one way (no circle), and nothing under ``neuralbrdf`` imports the ``export/``
scripts.  These tests run the contracts on the package, check that every package and module has a
floor, and break a copy of the package once per rule to show that each contract can fail."""

import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "neuralbrdf"
#: import-linter on the package under the working folder, without its cache (nothing written there).
LINT = "import sys; from importlinter.cli import lint_imports; sys.exit(lint_imports(no_cache=True, no_logo=True))"


def contracts() -> dict[str, dict]:
    """The contracts of pyproject.toml by id."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["importlinter"]
    return {contract["id"]: contract for contract in config["contracts"]}


def lint(root: Path) -> subprocess.CompletedProcess:
    """import-linter run on the ``neuralbrdf`` and ``export`` packages found in ``root``."""
    env = {**os.environ, "PYTHONPATH": str(root)}
    return subprocess.run([sys.executable, "-c", LINT], cwd=root, env=env, capture_output=True, text=True,
                          timeout=300)


def test_the_import_contracts_are_kept():
    result = lint(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    for contract in contracts().values():
        assert f"{contract['name']} KEPT" in result.stdout, result.stdout


def test_every_package_and_module_has_a_floor():
    """A new top-level package or module is placed in the layers, else the contract would not check it."""
    placed = {name.strip().removeprefix("neuralbrdf.")
              for layer in contracts()["layers"]["layers"] for name in layer.replace("|", ":").split(":")}
    groups = {p.stem if p.suffix == ".py" else p.name for p in PACKAGE.iterdir()
              if (p.suffix == ".py" and p.stem != "__init__") or (p.is_dir() and (p / "__init__.py").exists())}
    assert groups <= placed, f"not in any layer of pyproject.toml's contract: {sorted(groups - placed)}"


def _not_python(folder: str, names: list[str]) -> list[str]:
    """What :func:`copy_of_the_package` leaves out: caches, links and every file but Python source."""
    return [name for name in names if name == "__pycache__" or Path(folder, name).is_symlink()
            or (not Path(folder, name).is_dir() and not name.endswith(".py"))]


def copy_of_the_package(tmp_path: Path) -> Path:
    """The Python files of ``neuralbrdf`` and ``export/`` and pyproject.toml, copied under ``tmp_path``."""
    for name in ("neuralbrdf", "export"):
        shutil.copytree(ROOT / name, tmp_path / name, ignore=_not_python)
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    return tmp_path


BREAKS = {
    # a function-level import climbing from the physics floor to the Lightning one
    "layers": ("neuralbrdf/physics/bad.py", "def f():\n    from neuralbrdf.lightning.run import main\n"),
    # the mutual import that render/load_time.py removed
    "no-circle": ("neuralbrdf/render/measured_bsdf.py", "\nfrom neuralbrdf.render import mitsuba_bsdf\n"),
    "no-export-scripts": ("neuralbrdf/cli/bad.py", "import export.to_onnx\n"),
}


@pytest.mark.parametrize("contract", sorted(BREAKS))
def test_a_broken_rule_breaks_its_contract(tmp_path, contract):
    """The same run on a copy with one bad import fails on that contract (an upward import between
    packages is a circle between them too)."""
    root = copy_of_the_package(tmp_path)
    file, line = BREAKS[contract]
    with open(root / file, "a", encoding="utf-8") as handle:
        handle.write(line)
    result = lint(root)
    assert result.returncode == 1, result.stdout + result.stderr
    assert f"{contracts()[contract]['name']} BROKEN" in result.stdout, result.stdout
