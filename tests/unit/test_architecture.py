"""The house stays clear: every import of the project's modules, read with ast, points the way the
README's Architecture section draws it (library <- runners <- CLIs; benchmark and tools on top), and no
two modules import each other in a circle, imports for type hints only (`TYPE_CHECKING`) included: a type
both sides need belongs in a lower module."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RUNNERS = ("clipclique.mapping", "clipclique.localization")  # the two tools: their runners and CLIs
BENCHMARK = "clipclique.benchmark"
CLI_MODULES = {"clipclique.mapping.cli", "clipclique.localization.cli"}  # argument parsing and printing only
API = "clipclique.api"  # the public names, on top of the library and both runners; only the package re-exports them


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def sources() -> dict[str, Path]:
    """Module name -> file, for the package and tools/ (as tools.NAME)."""
    found = {module_name(p): p for p in (ROOT / "clipclique").rglob("*.py")}
    found |= {f"tools.{p.stem}": p for p in (ROOT / "tools").glob("*.py")}
    return found


def imports(path: Path, known: set[str]) -> Iterator[str]:
    """The project modules `path` imports (anywhere in the file: functions and `TYPE_CHECKING` blocks too)."""
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:  # a submodule, else the module
            names = [f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in known else node.module
                     for a in node.names]
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
    assert {"clipclique.pipeline", "clipclique.localization.run", "clipclique.mapping.run",
            "clipclique.benchmark.suite",
            "tools.demo"} <= set(graph)
    assert "clipclique.pipeline" in graph["clipclique.localization.run"]
    assert "clipclique.mapping.run" in graph["tools.demo"]
    assert "clipclique.localization.runs" in graph["clipclique.localization.results"]  # a former type-only import


def test_the_library_imports_no_tool_runner_or_benchmark(graph):
    assert offenders(graph, ("clipclique",), (*RUNNERS, BENCHMARK, "tools"), exempt=(*RUNNERS, BENCHMARK, API)) == []


def test_the_api_is_the_top_layer(graph):
    """Nothing in the project imports clipclique.api but the package's lazy re-export (type-only), and the api
    reaches both runners (it wraps them, copying nothing)."""
    assert sorted(a for a, targets in graph.items() if API in targets) == ["clipclique"]
    assert {"clipclique.localization.run", "clipclique.mapping.build", "clipclique.pipeline"} <= graph[API]


def test_readers_never_import_the_simulation(graph):
    """A generated scene is an ordinary ScanNet or TUM folder: the readers do not know it was made."""
    assert offenders(graph, ("clipclique.datasets",), ("clipclique.sim",)) == []


def test_only_the_registries_import_the_simulation(graph):
    """The registries (backends, resolve) sit above the real and the simulated back-ends; the rest of
    the library, real back-ends included, never reaches into clipclique.sim, and sim never into them.
    The runners and the benchmark sit above the registries."""
    registries = ("clipclique.backends", "clipclique.resolve")
    assert offenders(graph, ("clipclique",), ("clipclique.sim",),
                     exempt=("clipclique.sim", *registries, *RUNNERS, BENCHMARK)) == []
    assert offenders(graph, ("clipclique.sim",), registries) == []


def test_no_module_imports_a_cli_module(graph):
    """Tools, the benchmark and tests call runners (clipclique.localization.run, clipclique.mapping.run), never a
    CLI."""
    assert sorted(f"{a} imports {b}" for a, targets in graph.items() for b in targets if b in CLI_MODULES) == []


def test_the_two_tools_meet_only_in_the_map_file(graph):
    assert offenders(graph, ("clipclique.mapping",), ("clipclique.localization",)) == []
    assert offenders(graph, ("clipclique.localization",), ("clipclique.mapping",)) == []


def test_only_tools_import_the_benchmark(graph):
    assert offenders(graph, ("clipclique",), (BENCHMARK,), exempt=(BENCHMARK,)) == []


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Each module that imports itself through others, as the path that closes the circle."""
    state: dict[str, int] = {}  # 1 on the path being walked, 2 done
    found: list[list[str]] = []

    def walk(name: str, path: list[str]) -> None:
        state[name] = 1
        for target in sorted(graph[name] - {name}):
            if state.get(target) == 1:
                found.append(path[path.index(target):] + [target])
            elif target not in state:
                walk(target, path + [target])
        state[name] = 2

    for name in sorted(graph):
        if name not in state:
            walk(name, [name])
    return found


def test_no_import_circles(graph):
    """Between files: function-level and type-only imports count."""
    assert circles(graph) == []


def test_the_circle_finder_finds_a_circle():
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c", "a"]]


# The rooms of the core, lowest first: a room imports only rooms before it (and the modules every room may use:
# errors, types, outcomes, config). A type both need lives in the lower one.
STAGES = ("clipclique.io", "clipclique.perception", "clipclique.descriptors", "clipclique.pose", "clipclique.verify",
          "clipclique.inliers", "clipclique.multiframe")
BASE = ("clipclique.errors", "clipclique.types", "clipclique.outcomes", "clipclique.blas", "clipclique.commands",
        "clipclique.exits")


def test_the_rooms_import_only_rooms_below(graph):
    upward = [f"{a} imports {b}" for a, targets in graph.items() for b in targets for i, room in enumerate(STAGES)
              if under(a, room) and under(b, *STAGES[i + 1:])]
    assert upward == []


def test_the_base_modules_import_no_room(graph):
    assert offenders(graph, BASE, STAGES) == []


def test_every_room_is_there(graph):
    """Each room holds modules (a renamed room would pass the order test empty)."""
    assert all(any(under(name, room) and name != room for name in graph) for room in STAGES)


CONFIG = {"clipclique.config", "clipclique.config.schema", "clipclique.config.presets", "clipclique.config.overrides"}


def test_the_config_package_is_schema_then_presets_then_overrides(graph):
    """The settings (schema) <- the methods as presets of them <- a configuration built from a preset, a file and
    overrides, and checked <- the package's front door, which every room imports; below the rooms, but for the
    strict file reader of io."""
    within = {name: graph[name] & CONFIG for name in CONFIG}
    assert within == {"clipclique.config.schema": set(), "clipclique.config.presets": {"clipclique.config.schema"},
                      "clipclique.config.overrides": {"clipclique.config.schema", "clipclique.config.presets"},
                      "clipclique.config": CONFIG - {"clipclique.config"}}
    beyond = set().union(*(graph[name] for name in CONFIG)) - CONFIG
    assert beyond <= {"clipclique.errors", "clipclique.types", "clipclique.io.safeio"}


def test_the_geometry_jobs_sit_in_their_rooms(graph):
    """What clipclique/geometry.py held, each job where its users are: ellipsoid fits and depth filtering in
    perception (observations, the map builder), pose errors in pose (metrics, multiframe, the runners), the
    simulator's poses in sim; each imports nothing above it."""
    assert "clipclique.geometry" not in graph
    assert graph["clipclique.perception.depth"] == set()
    assert graph["clipclique.perception.ellipsoids"] == {"clipclique.config", "clipclique.perception.depth",
                                                         "clipclique.types"}
    assert graph["clipclique.pose.distance"] == {"clipclique.types"}
    assert graph["clipclique.sim.poses"] == {"clipclique.types"}


def test_the_rooms_and_the_base_never_import_the_composition(graph):
    """`clipclique.pipeline` only composes the stages (each stage's wiring, e.g. descriptors.query,
    inliers.hypotheses, verify.ranking, lives in its room): no room or base module reaches back up into it."""
    assert offenders(graph, (*STAGES, *BASE), ("clipclique.pipeline",)) == []
    assert {"clipclique.descriptors.query", "clipclique.inliers.hypotheses",
            "clipclique.verify.ranking"} <= graph["clipclique.pipeline"]
