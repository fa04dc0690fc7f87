"""The package's layers point one way: every import, at module level or inside a
function, goes from a floor to the same floor or one below, and the packages never import each
other in a cycle.  Read bottom-up::

    conventions + the ONNX file contract → physics → data → virtual instrument →
    sources, models → losses/metrics/fitting → kinds → export, render → evaluation →
    Lightning → study, level of detail (lod), command line
"""

import ast
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "neuralbrdf"

#: Bottom to top; a module's group is its first name under ``neuralbrdf``.
FLOORS = (
    {"errors", "limits", "atomic", "folder_lock", "geometry", "configs_dir", "onnx_contract", "shipped", "console",
     "settings_file"},
    {"physics"},
    {"data"},
    {"virtual"},
    {"sources", "models", "checkpoints", "plotting"},
    {"losses", "metrics", "fitting"},
    {"kinds"},
    {"onnx_export", "render"},
    {"evaluation"},
    {"explorer"},
    {"lightning"},
    {"study", "lod", "acquisition", "exporting", "cli", "api", "__main__"},
)
FLOOR = {group: level for level, groups in enumerate(FLOORS) for group in groups}


def _group(module: str) -> str:
    """``export`` for the scripts folder, else the first name under ``neuralbrdf`` (``neuralbrdf``
    for the package itself)."""
    parts = module.split(".")
    if parts[0] != "neuralbrdf":
        return parts[0]
    return parts[1] if len(parts) > 1 else "neuralbrdf"


def import_edges() -> set[tuple[str, str, str]]:
    """``(file, importing group, imported group)`` for every ``neuralbrdf`` import in the package."""
    modules = {".".join(p.relative_to(PACKAGE.parent).with_suffix("").parts).removesuffix(".__init__")
               for p in PACKAGE.rglob("*.py")}
    edges = set()
    for path in PACKAGE.rglob("*.py"):
        module = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts).removesuffix(".__init__")
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in ("neuralbrdf", "export"):
                targets = [f"{node.module}.{alias.name}" for alias in node.names]
                targets = [t if t in modules else node.module for t in targets]
            elif isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names if alias.name.split(".")[0] in ("neuralbrdf", "export")]
            else:
                continue
            for target in targets:
                edges.add((str(path.relative_to(PACKAGE.parent)), _group(module), _group(target)))
    return edges


def test_every_group_has_a_floor():
    groups = {p.relative_to(PACKAGE).parts[0].removesuffix(".py") for p in PACKAGE.glob("*") if
              (p.suffix == ".py" and p.stem != "__init__") or (p.is_dir() and (p / "__init__.py").exists())}
    assert groups <= set(FLOOR), f"groups without a floor: {sorted(groups - set(FLOOR))}"


def test_imports_never_point_up():
    edges = import_edges()
    unplaced = sorted({f"{file}: imports {dst}" for file, _, dst in edges if dst not in FLOOR and dst != "neuralbrdf"})
    assert not unplaced, "imports of modules without a floor:\n" + "\n".join(unplaced)
    upward = sorted(f"{file}: {src} (floor {FLOOR[src]}) imports {dst} (floor {FLOOR[dst]})"
                    for file, src, dst in edges
                    if src in FLOOR and dst in FLOOR and FLOOR[dst] > FLOOR[src])
    assert not upward, "\n".join(upward)


def test_groups_import_each_other_in_no_cycle():
    graph: dict[str, set[str]] = {}
    for _, src, dst in import_edges():
        if src != dst and "neuralbrdf" not in (src, dst):
            graph.setdefault(src, set()).add(dst)
    visiting, done = [], set()

    def visit(node):
        if node in visiting:
            raise AssertionError("import cycle: " + " -> ".join(visiting[visiting.index(node):] + [node]))
        if node in done:
            return
        visiting.append(node)
        for nxt in sorted(graph.get(node, ())):
            visit(nxt)
        visiting.pop()
        done.add(node)

    for node in sorted(graph):
        visit(node)


def test_the_package_never_imports_export_scripts():
    assert not [edge for edge in import_edges() if edge[2] == "export"]


def test_a_broken_layering_is_caught(tmp_path, monkeypatch):
    """The checks can fail: a physics module importing the Lightning layer is reported."""
    fake = tmp_path / "neuralbrdf"
    (fake / "physics").mkdir(parents=True)
    (fake / "physics" / "__init__.py").write_text("")
    (fake / "physics" / "bad.py").write_text("from neuralbrdf.lightning.run import main\n")
    (fake / "lightning").mkdir()
    (fake / "lightning" / "__init__.py").write_text("")
    (fake / "lightning" / "run.py").write_text("from neuralbrdf.physics import bad\n")
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", fake)
    edges = import_edges()
    assert ("neuralbrdf/physics/bad.py", "physics", "lightning") in edges
    try:
        test_imports_never_point_up()
    except AssertionError as error:
        assert "physics (floor 1) imports lightning" in str(error)
    else:
        raise AssertionError("an upward import was not reported")


@pytest.mark.parametrize("line", ["from export.to_onnx import main\n", "import export.render\n"])
def test_an_import_of_the_export_scripts_is_caught(tmp_path, monkeypatch, line):
    fake = tmp_path / "neuralbrdf"
    (fake / "cli").mkdir(parents=True)
    (fake / "cli" / "__init__.py").write_text("")
    (fake / "cli" / "bad.py").write_text(line)
    monkeypatch.setattr(sys.modules[__name__], "PACKAGE", fake)
    with pytest.raises(AssertionError):
        test_the_package_never_imports_export_scripts()
