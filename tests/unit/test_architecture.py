"""The house stays clear: every import of the project's modules, read with ast, points the way the
README's Architecture section draws it (library <- runners <- CLIs; benchmark and tools on top),
and no two modules import each other in a circle."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("clipclique", "mapping", "localization", "benchmark")
CLI_MODULES = {"mapping.cli", "localization.cli"}  # argument parsing and printing only


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def sources() -> dict[str, Path]:
    """Module name -> file, for the packages and tools/ (as tools.NAME)."""
    found = {module_name(p): p for package in PACKAGES for p in (ROOT / package).rglob("*.py")}
    found |= {f"tools.{p.stem}": p for p in (ROOT / "tools").glob("*.py")}
    return found


def type_checking_lines(tree: ast.Module) -> set[int]:
    """Lines inside `if TYPE_CHECKING:` blocks: imports for annotations only, never run."""
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", getattr(node.test, "attr", None)) == "TYPE_CHECKING":
            for child in node.body:
                lines.update(range(child.lineno, (child.end_lineno or child.lineno) + 1))
    return lines


def imports(path: Path, known: set[str]) -> Iterator[str]:
    """The project modules `path` imports at run time (anywhere in the file, functions included)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skipped = type_checking_lines(tree)
    for node in ast.walk(tree):
        if getattr(node, "lineno", None) in skipped:
            continue
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:  # a submodule, else the module
            names = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in known else node.module for a in node.names]
        else:
            continue
        yield from (name for name in names if name in known)


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports."""
    found = sources()
    return {name: set(imports(path, set(found))) for name, path in found.items()}


def under(name: str, *rooms: str) -> bool:
    return any(name == room or name.startswith(room + ".") for room in rooms)


def offenders(graph: dict[str, set[str]], importer: tuple[str, ...], imported: tuple[str, ...],
              exempt: tuple[str, ...] = ()) -> list[str]:
    return sorted(f"{a} imports {b}" for a, targets in graph.items() for b in targets
                  if under(a, *importer) and not under(a, *exempt) and under(b, *imported))


def test_the_scan_sees_the_project(graph):
    """A scan that found nothing would pass every rule below."""
    assert {"clipclique.pipeline", "localization.run", "mapping.run", "benchmark.suite", "tools.demo"} <= set(graph)
    assert "clipclique.pipeline" in graph["localization.run"] and "mapping.run" in graph["tools.demo"]


def test_the_library_imports_no_tool_runner_or_benchmark(graph):
    assert offenders(graph, ("clipclique",), ("mapping", "localization", "benchmark", "tools")) == []


def test_readers_never_import_the_simulation(graph):
    """A generated scene is an ordinary ScanNet or TUM folder: the readers do not know it was made."""
    assert offenders(graph, ("clipclique.datasets",), ("clipclique.sim",)) == []


def test_only_the_registries_import_the_simulation(graph):
    """The registries (backends, resolve) sit above the real and the simulated back-ends; the rest of
    the library, real back-ends included, never reaches into clipclique.sim, and sim never into them."""
    registries = ("clipclique.backends", "clipclique.resolve")
    assert offenders(graph, ("clipclique",), ("clipclique.sim",), exempt=("clipclique.sim", *registries)) == []
    assert offenders(graph, ("clipclique.sim",), registries) == []


def test_no_module_imports_a_cli_module(graph):
    """Tools, the benchmark and tests call runners (localization.run, mapping.run), never a CLI."""
    assert sorted(f"{a} imports {b}" for a, targets in graph.items() for b in targets if b in CLI_MODULES) == []


def test_the_two_tools_meet_only_in_the_map_file(graph):
    assert offenders(graph, ("mapping",), ("localization",)) == []
    assert offenders(graph, ("localization",), ("mapping",)) == []


def test_only_tools_import_the_benchmark(graph):
    assert offenders(graph, PACKAGES, ("benchmark",), exempt=("benchmark",)) == []


def test_no_import_circles(graph):
    """Between files: a module that imports itself through others (function-level imports too)."""
    state: dict[str, int] = {}  # 1 on the path being walked, 2 done
    circles: list[list[str]] = []

    def walk(name: str, path: list[str]) -> None:
        state[name] = 1
        for target in sorted(graph[name] - {name}):
            if state.get(target) == 1:
                circles.append(path[path.index(target):] + [target])
            elif target not in state:
                walk(target, path + [target])
        state[name] = 2

    for name in sorted(graph):
        if name not in state:
            walk(name, [name])
    assert circles == []
