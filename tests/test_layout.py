"""The package layout follows the data path (README, "Layout"): cost/ -> aggregate/ -> select/, models/, with
the compiled kernels in kernels/ and the one registry in matchers/. These tests read the imports (ast) of every
module, so a new import that breaks the layout fails here."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "stereonet"
STAGES = ("cost", "aggregate", "select", "kernels", "models")


def _imports() -> dict[str, set[str]]:
    """Top-level subpackage/module of stereonet -> the stereonet subpackages/modules it imports."""
    edges: dict[str, set[str]] = {}
    for path in PACKAGE.rglob("*.py"):
        src = path.relative_to(PACKAGE).parts[0].removesuffix(".py")
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("stereonet"):
                names = ([f"stereonet.{a.name}" for a in node.names] if node.module == "stereonet"
                         else [node.module])
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names if a.name.startswith("stereonet")]
            else:
                continue
            for name in names:
                parts = name.split(".")
                if len(parts) > 1 and parts[1] != src:
                    edges.setdefault(src, set()).add(parts[1])
    return edges


def test_no_stage_imports_the_registry_or_a_later_tool():
    edges = _imports()
    for stage in STAGES:
        bad = edges.get(stage, set()) & {"matchers", "cli", "evaluation"}
        assert not bad, f"stereonet.{stage} imports {sorted(bad)}"


def test_kernels_import_nothing_but_the_checks():
    assert _imports().get("kernels", set()) <= {"checks"}


def test_no_import_cycle_between_the_data_path_packages():
    edges = _imports()
    nodes = set(STAGES) | {"matchers"}

    def reaches(a: str, b: str, seen: set[str]) -> bool:
        for n in edges.get(a, set()) & nodes:
            if n == b or (n not in seen and reaches(n, b, seen | {n})):
                return True
        return False

    cycles = sorted(a for a in nodes if reaches(a, a, {a}))
    assert not cycles, f"import cycle through {cycles}"


def test_the_registry_holds_every_matcher_and_the_stages_are_where_the_readme_says():
    from stereonet import matchers

    for name in matchers.available():
        module = matchers.spec(name).fn.__module__
        assert module.startswith("stereonet.matchers."), f"{name} is registered in {module}"
    for pkg in ("cost", "aggregate", "select", "kernels", "matchers"):
        assert (PACKAGE / pkg / "__init__.py").is_file()
    assert not (PACKAGE / "optimize").exists() and not (PACKAGE / "matchers.py").exists()
