"""The module import graph of ``ompn_ros`` and ``sim_nodes`` has no cycles; the rooms keep their sizes
(classes, functions) and their private state (the checks at the end).

Every module is parsed with :mod:`ast` (nothing is imported).  An edge ``a -> b`` is any import of
project module ``b`` anywhere in ``a``: at module level, inside a function, or under
``if TYPE_CHECKING:``.  Relative imports are resolved, and ``from pkg import name`` points at the
submodule ``pkg.name`` when that is a module, otherwise at ``pkg`` itself.  Parent packages that
Python initialises on the way are not edges (a package ``__init__`` re-exporting its submodules is
not a circle).

Function-local imports of project modules are counted as well: they are how circles used to be
hidden.  There is one, listed in ``LOCAL_IMPORTS`` (an optional heavy dependency loaded only when its
feature is used).  The modules of ``LIGHT_HELP`` import their services inside the functions that
run them, so that ``--help`` loads no torch (``test/house/test_help_light.py``); every other module imports
at module level.
"""

from __future__ import annotations

import ast
import functools
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("ompn_ros", "sim_nodes")
LOCAL_IMPORTS = {
    "ompn_ros.model.streaming": "numba, for the 'jit' backend only",
    "ompn_ros.app.replay": "the sims (MuJoCo, gymnasium), for --generate only: a bag's replay loads none",
}
"""The function-local project imports allowed (module -> why)."""
LIGHT_HELP = {
    "ompn_ros.cli.segment": "the replay and tuning services (torch) load when the command runs",
    "ompn_ros.cli.train": "the training services (torch) load when the command runs",
    "ompn_ros.cli.ensemble": "the ensemble service (torch) loads when the command runs",
    "ompn_ros.cli._batch": "the batch services load when a batch runs",
    "ompn_ros.cli._dataset": "the LeRobot dataset services (torch) load when a dataset is segmented",
    "ompn_ros.app.segment_setup": "offers ompn_segment's choices; what it sets up loads on use",
    "ompn_ros.app.closed_loop": "offers ompn_closed_loop's tasks; the model loads with a checkpoint",
    "ompn_ros.nodes.ompn_node": "torch and the model load at configure",
}
"""Modules whose function-local project imports keep a command's ``--help`` light (module -> what)."""
SIM_NODES_MAY_IMPORT = (
    "ompn_ros.layout", "ompn_ros.errors", "ompn_ros.data.episode", "ompn_ros.data.messages",
    "ompn_ros.ros.params", "ompn_ros.ros.run", "ompn_ros.validate",
)
"""The public ompn_ros API sim_nodes uses (see ``sim_nodes/__init__.py``)."""
OMPN_ROS_MAY_IMPORT = ("sim_nodes.registry",)
"""The sim_nodes module ompn_ros uses (see ``sim_nodes/__init__.py``)."""


def _modules() -> dict[str, Path]:
    found: dict[str, Path] = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            found[name] = path
    return found


MODULES = _modules()


@functools.cache
def _parsed(path: Path) -> ast.Module:
    """The syntax tree of ``path``, parsed once for all the checks of this module (nothing mutates it)."""
    return ast.parse(path.read_text(), str(path))


@functools.cache
def _graph() -> tuple[dict[str, set[str]], list[str]]:
    """Edges between project modules, and one ``module:line -> target`` per function-local import
    (computed once; callers only read it)."""
    return _build_graph()


def _is_package(name: str) -> bool:
    return name in MODULES and MODULES[name].name == "__init__.py"


def _imports(module: str, tree: ast.Module) -> Iterator[tuple[str, bool, int]]:
    """``(imported project module, function-local?, line)`` for every import in ``tree``."""
    local_nodes = {
        id(inner)
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        for inner in ast.walk(node)
    }
    base = module if _is_package(module) else module.rpartition(".")[0]
    for node in ast.walk(tree):
        local = id(node) in local_nodes
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in MODULES:
                    yield alias.name, local, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = base.split(".")
                anchor = parts[: len(parts) - node.level + 1]
                target = ".".join(anchor + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in MODULES:
                    yield sub, local, node.lineno
                elif target in MODULES:
                    yield target, local, node.lineno


def _build_graph() -> tuple[dict[str, set[str]], list[str]]:
    edges: dict[str, set[str]] = {name: set() for name in MODULES}
    local: set[str] = set()
    for name, path in MODULES.items():
        for target, is_local, line in _imports(name, _parsed(path)):
            if target != name:
                edges[name].add(target)
            if is_local:
                local.add(f"{name}:{line} -> {target}")
    return edges, sorted(local)


def _find_cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per strongly connected component with more than one module (Tarjan, O(V + E))."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                components.append(sorted(component))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return [_one_cycle(edges, set(c), c[0]) for c in components]


def _one_cycle(edges: dict[str, set[str]], members: set[str], start: str) -> list[str]:
    """A shortest path from ``start`` back to itself inside one component (breadth first)."""
    parents: dict[str, str] = {}
    frontier = [start]
    while frontier:
        following = []
        for v in frontier:
            for w in sorted(edges[v] & members):
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(parents[path[-1]])
                    return [start, *reversed(path[:-1]), start] if len(path) > 1 else [start, v, start]
                if w not in parents:
                    parents[w] = v
                    following.append(w)
        frontier = following
    return [start]


def test_the_graph_sees_known_edges():
    edges, _ = _graph()
    assert "ompn_ros.model.config" in edges["ompn_ros.model.checkpoint"]
    assert "ompn_ros.data.episode" in edges["sim_nodes.craft.expert"]
    assert "sim_nodes" in edges["sim_nodes.ros_common"]  # from sim_nodes import derive_seed


def test_cycle_finder_reports_a_cycle():
    edges = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _find_cycles(edges) == [["a", "b", "c", "a"]]
    assert _find_cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycles():
    edges, _ = _graph()
    cycles = _find_cycles(edges)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_modules_import_at_top_level():
    _, local = _graph()
    local = [entry for entry in local if entry.split(":")[0] not in LIGHT_HELP]
    unexpected = [entry for entry in local if entry.split(":")[0] not in LOCAL_IMPORTS]
    assert not unexpected, "function-local imports of project modules:\n" + "\n".join(unexpected)
    assert len(local) <= len(LOCAL_IMPORTS)


def test_sim_nodes_use_only_the_public_api():
    edges, _ = _graph()
    offenders = [
        f"{name} -> {target}"
        for name, targets in edges.items()
        if name.startswith("sim_nodes")
        for target in targets
        if target.startswith("ompn_ros") and target not in SIM_NODES_MAY_IMPORT
    ]
    assert not offenders, "sim_nodes imports ompn_ros internals:\n" + "\n".join(offenders)


def test_ompn_ros_reaches_the_domains_through_the_registry():
    edges, _ = _graph()
    offenders = [
        f"{name} -> {target}"
        for name, targets in edges.items()
        if name.startswith("ompn_ros")
        for target in targets
        if target.startswith("sim_nodes") and target not in OMPN_ROS_MAY_IMPORT
    ]
    assert not offenders, "ompn_ros imports sim_nodes around sim_nodes.registry:\n" + "\n".join(offenders)


FLOORS: dict[str, int] = {
    # the base: names, rules and errors every layer uses
    "ompn_ros": 0, "ompn_ros.errors": 0, "ompn_ros.layout": 0, "ompn_ros.paths": 0,
    "ompn_ros.validate": 0, "ompn_ros.metrics": 0, "ompn_ros.checkpoints": 0, "ompn_ros.atomic": 0,
    "ompn_ros.data": 1,  # episodes, the codec, bags in and out, the cache
    "ompn_ros.model": 2,
    "ompn_ros.detect": 3,
    "ompn_ros.segmenter": 4, "ompn_ros.stream": 4, "ompn_ros.plotting": 4,
    "ompn_ros.train": 5,
    "ompn_ros.ros": 6,  # parameters, containment, run_node, launch description
    "sim_nodes": 7,
    "ompn_ros.app": 8,  # the services of the commands
    "ompn_ros.nodes": 9, "ompn_ros.cli": 9,
}
"""The floors of the package, lowest first: a module imports only its own room or lower floors.
A room is the longest prefix of a module's name listed here."""


def _room(module: str) -> str:
    return max((p for p in FLOORS if module == p or module.startswith(p + ".")), key=len)


def test_every_module_has_a_floor():
    edges, _ = _graph()
    assert {_room(name) for name in edges} >= {"ompn_ros.data", "ompn_ros.app", "ompn_ros.ros", "sim_nodes"}


def test_no_import_runs_back_up():
    edges, _ = _graph()
    upward = [
        f"{name} (floor {FLOORS[_room(name)]}) -> {target} (floor {FLOORS[_room(target)]})"
        for name, targets in sorted(edges.items())
        for target in sorted(targets)
        if FLOORS[_room(target)] > FLOORS[_room(name)]
    ]
    assert not upward, "imports that run back up:\n" + "\n".join(upward)


def test_floor_check_sees_an_upward_import():
    assert FLOORS[_room("ompn_ros.data.reader.read")] < FLOORS[_room("ompn_ros.segmenter")]
    assert _room("ompn_ros.app.replay") == "ompn_ros.app"


def _imported_roots(node: ast.AST) -> list[str]:
    if isinstance(node, ast.Import):
        return [alias.name.split(".")[0] for alias in node.names]
    if isinstance(node, ast.ImportFrom) and not node.level:
        return [(node.module or "").split(".")[0]]
    return []


def test_the_product_never_imports_the_lab():
    offenders = [
        f"{name}:{node.lineno}"
        for name, path in MODULES.items()
        for node in ast.walk(_parsed(path))
        if "lab" in _imported_roots(node)
    ]
    assert not offenders, "product modules importing lab/: " + ", ".join(offenders)
    assert (ROOT / "lab" / "pipeline.py").is_file() and not (ROOT / "ompn_ros" / "experiments").exists()


CLI_MAY_IMPORT = ("ompn_ros.app", "ompn_ros.cli")
"""The rooms a command-line shell imports from (besides :mod:`ompn_ros.errors`): the work is a service."""


def test_the_command_lines_import_only_the_app_layer():
    edges, _ = _graph()
    offenders = [
        f"{name} -> {target}"
        for name, targets in sorted(edges.items())
        if _room(name) == "ompn_ros.cli"
        for target in sorted(targets)
        if target != "ompn_ros.errors" and _room(target) not in CLI_MAY_IMPORT
    ]
    assert not offenders, "command-line shells importing below the app layer:\n" + "\n".join(offenders)


CUTS = "ompn_ros.data.cuts"
"""The package of the rules that cut a stream (gap, idle, still, repeats), each in one module."""


def test_the_cuts_of_a_stream_have_one_room_reached_through_its_face():
    edges, _ = _graph()
    old_homes = {"ompn_ros.data.idle", "ompn_ros.data.still", "ompn_ros.data.repeats", "ompn_ros.stream.gap"}
    assert not old_homes & set(MODULES), "a cut rule outside ompn_ros/data/cuts/"
    assert {f"{CUTS}.{rule}" for rule in ("gap", "idle", "still", "repeats")} <= set(MODULES)
    bypassing = [
        f"{name} -> {target}"
        for name, targets in sorted(edges.items())
        if not name.startswith(CUTS)
        for target in sorted(targets)
        if target.startswith(CUTS + ".")
    ]
    assert not bypassing, f"imports around the face of {CUTS}:\n" + "\n".join(bypassing)


FACES = ("ompn_ros.data.cache",)
"""Packages with one face: every module outside the package (product, lab, benchmarks, tests)
imports the package itself, never one of its modules."""
CALLER_TREES = ("ompn_ros", "sim_nodes", "lab", "bench", "test")


def _deep_imports(face: str) -> list[str]:
    """``file:line -> module`` for each import of a module inside ``face`` from outside it."""
    found = []
    for tree_name in CALLER_TREES:
        for path in sorted((ROOT / tree_name).rglob("*.py")):
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            if module == face or module.startswith(face + "."):
                continue
            for target, _, line in _imports(module, _parsed(path)):
                if target.startswith(face + "."):
                    found.append(f"{path.relative_to(ROOT)}:{line} -> {target}")
    return found


def test_packages_with_one_face_are_entered_through_it():
    assert any(name.startswith("ompn_ros.data.cache.") for name in MODULES), "the cache is a package"
    offenders = [entry for face in FACES for entry in _deep_imports(face)]
    assert not offenders, "imports around a package's face:\n" + "\n".join(offenders)


BAG_RUN = (
    "ompn_ros.cli.segment", "ompn_ros.app.replay", "ompn_ros.app.detector_tuning", "ompn_ros.app.errors",
    "ompn_ros.app.read_report", "ompn_ros.app.segment_setup", "ompn_ros.model.load",
    "ompn_ros.detect.settings", "ompn_ros.detect.tune",
)
"""What ``ompn_segment --bag`` imports (``cli/segment.py``'s ``_run`` and the setup it calls)."""
SIMS = ("mujoco", "gymnasium", "sim_nodes")


def test_segmenting_a_bag_loads_no_simulator():
    code = (f"import importlib, sys\nfor m in {BAG_RUN!r}: importlib.import_module(m)\n"
            f"print(sorted(m for m in sys.modules if m.split('.')[0] in {SIMS!r}))")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT,
                         timeout=300, check=True)
    assert out.stdout.strip() == "[]", f"ompn_segment on a bag loads the sims: {out.stdout.strip()}"


def test_the_lab_indexes_every_module():
    """``lab/__init__.py`` and ``lab/README.md`` (study -> module -> results -> log) name every module."""
    modules = {p.stem for p in (ROOT / "lab").glob("*.py") if p.stem != "__init__"}
    indexed = set(re.findall(r"~lab\.(\w+)", (ROOT / "lab" / "__init__.py").read_text()))
    in_readme = set(re.findall(r"`(\w+)`", (ROOT / "lab" / "README.md").read_text())) & modules
    assert indexed == modules, f"lab/__init__.py: {sorted(modules ^ indexed)} missing or gone"
    assert in_readme == modules, f"lab/README.md misses {sorted(modules - in_readme)}"


# --- sizes and private state: the rooms measured ------------------------------------------------------
SIZED_TREES = ("ompn_ros", "sim_nodes", "lab")
"""The trees whose classes, functions and attribute reads the checks below measure."""
MAX_CLASS_LINES = 250
MAX_FUNCTION_LINES = 60
COMPILED_KERNELS = ("ompn_ros/model/_jit_stream.py", "ompn_ros/model/fused.py")
"""numba kernels: one long function each, written for the compiler, exempt from the function size."""

# Today's offenders, each with what keeps it: the list may only shrink (a listed entry that no longer
# offends fails too, so the list stays the truth), and anything NOT listed fails at once.
KNOWN_LARGE_CLASSES: dict[str, str] = {}
KNOWN_LONG_FUNCTIONS: dict[str, str] = {}
KNOWN_PRIVATE_READS: dict[str, str] = {}
LIBRARY_PRIVATE_STATE = {
    "ompn_ros.cli._common: parser._actions": "argparse has no public list of a parser's options",
    "ompn_ros.cli._common: parser._mutually_exclusive_groups": "argparse: no public list of the groups",
    "ompn_ros.cli._common: g._group_actions": "argparse: no public list of a group's options",
    "ompn_ros.nodes.lifecycle_guard: node._state_machine": "ROS client: no public lifecycle machine",
    "ompn_ros.nodes.ompn_node_inputs: sub._callback_type": "ROS client: message info, any executor",
    "ompn_ros.workers: os._exit": "the documented exit without cleanup",
    "ompn_ros.cli._batch: os._exit": "the documented exit without cleanup",
}
"""Private names of libraries (not rooms of this project) that the product uses, each with its reason."""
PUBLIC_UNDERSCORE_API = frozenset({"_replace", "_asdict", "_fields", "_make"})
"""Names that start with an underscore and are public API (namedtuple's)."""


def _sized_sources() -> Iterator[tuple[str, str, ast.Module]]:
    """``(path relative to the repository, module name, tree)`` of every module in ``SIZED_TREES``."""
    for tree_name in SIZED_TREES:
        for path in sorted((ROOT / tree_name).rglob("*.py")):
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
            yield path.relative_to(ROOT).as_posix(), module, _parsed(path)


def _definitions(tree: ast.Module) -> Iterator[tuple[str, ast.AST, int]]:
    """``(qualified name, node, lines from its ``def``/``class`` line to its last line)`` of every class
    and function, nested ones included."""
    def walk(node: ast.AST, prefix: str) -> Iterator[tuple[str, ast.AST, int]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
                name = f"{prefix}{child.name}"
                yield name, child, (child.end_lineno or child.lineno) - child.lineno + 1
                yield from walk(child, name + ".")
            else:
                yield from walk(child, prefix)
    yield from walk(tree, "")


def _oversized(path: str, tree: ast.Module, kind: type | tuple[type, ...], limit: int) -> dict[str, int]:
    """``{path::qualified name: lines}`` of each definition of ``kind`` longer than ``limit`` lines."""
    return {f"{path}::{name}": lines for name, node, lines in _definitions(tree)
            if isinstance(node, kind) and lines > limit}


def _private_reads(module: str, tree: ast.Module) -> set[str]:
    """``module: expr._name`` for each use of a single-underscore attribute on anything but
    ``self``, ``cls`` or ``super()``: another object's private state."""
    found = set()
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute):
            continue
        name, owner = node.attr, node.value
        if not name.startswith("_") or name.startswith("__") or name in PUBLIC_UNDERSCORE_API:
            continue
        if isinstance(owner, ast.Name) and owner.id in ("self", "cls"):
            continue
        if isinstance(owner, ast.Call) and isinstance(owner.func, ast.Name) and owner.func.id == "super":
            continue
        found.add(f"{module}: {ast.unparse(owner)}.{name}")
    return found


def _report(what: str, offenders: dict[str, int] | set[str]) -> str:
    items = [f"{k} ({v} lines)" for k, v in sorted(offenders.items())] if isinstance(offenders, dict) \
        else sorted(offenders)
    return f"{what}:\n" + "\n".join(items)


def test_no_class_is_over_250_lines():
    found: dict[str, int] = {}
    for path, _, tree in _sized_sources():
        found.update(_oversized(path, tree, ast.ClassDef, MAX_CLASS_LINES))
    new = {k: v for k, v in found.items() if k not in KNOWN_LARGE_CLASSES}
    assert not new, _report(f"classes over {MAX_CLASS_LINES} lines", new)
    stale = sorted(KNOWN_LARGE_CLASSES.keys() - found.keys())
    assert not stale, f"listed but no longer too large (take them off KNOWN_LARGE_CLASSES): {stale}"


def test_no_function_is_over_60_lines_outside_the_compiled_kernels():
    found: dict[str, int] = {}
    for path, _, tree in _sized_sources():
        if path not in COMPILED_KERNELS:
            found.update(_oversized(path, tree, (ast.FunctionDef, ast.AsyncFunctionDef), MAX_FUNCTION_LINES))
    new = {k: v for k, v in found.items() if k not in KNOWN_LONG_FUNCTIONS}
    assert not new, _report(f"functions over {MAX_FUNCTION_LINES} lines", new)
    stale = sorted(KNOWN_LONG_FUNCTIONS.keys() - found.keys())
    assert not stale, f"listed but no longer too long (take them off KNOWN_LONG_FUNCTIONS): {stale}"


def test_no_module_reaches_into_another_objects_private_state():
    found = set().union(*(_private_reads(module, tree) for _, module, tree in _sized_sources()))
    new = found - KNOWN_PRIVATE_READS.keys() - LIBRARY_PRIVATE_STATE.keys()
    assert not new, _report("reads of another object's private state (make it public, or ask its owner)", new)
    stale = sorted(KNOWN_PRIVATE_READS.keys() - found)
    assert not stale, f"listed but no longer read (take them off KNOWN_PRIVATE_READS): {stale}"


_OFFENDER = '''
class Big:
    def method(self):
        return self._mine, Big._helper
''' + "\n".join(f"    x{i} = {i}" for i in range(MAX_CLASS_LINES)) + '''

@decorated
def long(seg, node):
    """A function one line over the limit."""
''' + "\n".join(f"    y{i} = {i}" for i in range(MAX_FUNCTION_LINES - 2)) + '''
    return seg._last_stamp, node._detector, super()._own, cls._own, point._replace(x=1), node.__dict__
'''


def test_the_size_and_reach_checks_see_an_injected_offender():
    tree = ast.parse(_OFFENDER)
    assert set(_oversized("x.py", tree, ast.ClassDef, MAX_CLASS_LINES)) == {"x.py::Big"}
    functions = _oversized("x.py", tree, ast.FunctionDef, MAX_FUNCTION_LINES)
    assert functions == {"x.py::long": MAX_FUNCTION_LINES + 1}
    assert not _oversized("x.py", ast.parse("def short():\n    return 1\n"), ast.FunctionDef, 2)
    assert _private_reads("room.module", tree) == {
        "room.module: Big._helper", "room.module: seg._last_stamp", "room.module: node._detector"}


def test_the_known_offenders_are_real_files():
    listed = [*KNOWN_LARGE_CLASSES, *KNOWN_LONG_FUNCTIONS]
    assert all((ROOT / key.split("::")[0]).is_file() for key in listed), "a KNOWN_* entry names no file"
    modules = {key.split(":")[0] for key in [*KNOWN_PRIVATE_READS, *LIBRARY_PRIVATE_STATE]}
    assert modules <= set(MODULES), f"KNOWN_PRIVATE_READS names no module: {sorted(modules - set(MODULES))}"
