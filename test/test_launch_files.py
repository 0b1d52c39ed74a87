"""The launch files resolve in a colcon install space, checked without the ``launch`` package.

Each installed ``share/ompn_ros/launch/*.launch.py`` is read as an AST and its launch-time values are
evaluated statically (``DeclareLaunchArgument`` defaults, ``LaunchConfiguration``,
``FindPackageShare`` + ``PathJoinSubstitution``).  A launch file passes when

* every ``LaunchConfiguration`` names a declared argument, and arguments are declared once;
* every package-share path it joins exists in the install space;
* every ``Node`` runs an ``ompn_ros`` console script found in ``lib/ompn_ros``;
* every parameter key it passes (inline dicts and the node's section of every params file) is declared
  by that node's source in the install space (``declare_parameter`` / ``ParamSpec``), or is
  ``use_sim_time``, and reaches the node with the type of the declared default (``ParameterValue``
  ``value_type``, a literal, or the YAML value; a bare substitution of '' would be YAML null);
* every remapped name is a topic of ``ompn_ros/layout.py``;
* ``ompn_node`` gets a checkpoint: a required argument, an installed checkpoint directory, or the
  shipped checkpoint of the ``domain`` its params file sets.

The negative tests break one name at a time in a copy and expect the matching one-line error.
"""

from __future__ import annotations

import ast
import configparser
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
VENV_BIN = Path(sys.executable).parent
PACKAGE = "ompn_ros"
BUILTIN_PARAMETERS: dict[str, type | None] = {"use_sim_time": bool}  # declared by every rclpy node
VALUE_TYPES = {"bool": bool, "int": int, "float": float, "str": str}
LAUNCH_FILES = ("dial_sim.launch.py", "craft_sim.launch.py", "ompn_node.launch.py")


class LaunchCheckError(AssertionError):
    """A launch file names something the install space does not have; the message says what."""


@dataclass(frozen=True)
class Install:
    """The parts of a colcon install base that launch files resolve against."""

    base: Path

    @property
    def prefix(self) -> Path:
        return self.base / PACKAGE

    @property
    def share(self) -> Path:
        return self.prefix / "share" / PACKAGE

    @property
    def lib(self) -> Path:
        return self.prefix / "lib" / PACKAGE

    @property
    def site(self) -> Path:
        found = sorted(self.prefix.glob("lib/python3*/site-packages"))
        if not found:
            raise LaunchCheckError(f"no site-packages under {self.prefix}/lib")
        return found[0]


@dataclass
class LaunchSummary:
    """What a launch file starts, for assertions on top of the resolution checks."""

    arguments: dict[str, ast.expr | None] = field(default_factory=dict)
    executables: list[str] = field(default_factory=list)
    inline_parameters: dict[str, set[str]] = field(default_factory=dict)
    share_paths: list[Path] = field(default_factory=list)


# --- what the install space declares -------------------------------------------------------------
def _console_scripts(install: Install) -> dict[str, str]:
    """Console script name -> module, from the installed ``entry_points.txt`` (the scripts themselves
    are checked on disk)."""
    found = sorted(install.site.glob(f"{PACKAGE}-*.egg-info/entry_points.txt"))
    if not found:
        raise LaunchCheckError(f"no {PACKAGE} entry_points.txt in {install.site}")
    parser = configparser.ConfigParser()
    parser.read(found[0])
    return {name: target.split(":")[0].strip() for name, target in parser["console_scripts"].items()}


def _module_file(install: Install, module: str) -> Path:
    path = install.site / Path(*module.split("."))
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


def declared_parameters(install: Install, module: str) -> dict[str, type | None]:
    """Name -> type of the literal default (None: not a literal) of every ``declare_parameter`` /
    ``ParamSpec`` call in ``module`` and the package modules it imports from (one level: the sims'
    shared parameters live in ``sim_nodes.ros_common``)."""
    tree = ast.parse(_module_file(install, module).read_text())
    sources = [tree]
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            imported = _module_file(install, node.module)
            if node.module.split(".")[0] in ("ompn_ros", "sim_nodes") and imported.is_file():
                sources.append(ast.parse(imported.read_text()))
    names = dict(BUILTIN_PARAMETERS)
    for source in sources:
        for node in ast.walk(source):
            if isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
                func = node.func
                called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
                if called in ("declare_parameter", "ParamSpec") and isinstance(node.args[0].value, str):
                    names[node.args[0].value] = _literal_type(node.args[1] if len(node.args) > 1 else None)
    return names


def _literal_type(node: ast.expr | None) -> type | None:
    try:
        return type(ast.literal_eval(node)) if node is not None else None
    except ValueError:
        return None


def layout_topics(install: Install) -> set[str]:
    """The relative topic names of ``ompn_ros/layout.py``: its string constants without a '/', except
    the episode marker's status name, phases and keys (``EPISODE_*``, ``KEY_*``)."""
    tree = ast.parse((install.site / "ompn_ros" / "layout.py").read_text())
    topics = set()
    for node in tree.body:
        if isinstance(node, ast.AnnAssign) and isinstance(node.value, ast.Constant):
            name, value = getattr(node.target, "id", ""), node.value.value
            if name.startswith(("KEY_", "EPISODE_")) or not isinstance(value, str) or "/" in value:
                continue
            topics.add(value)
    return topics


# --- static evaluation of the launch file ---------------------------------------------------------
def _call_name(node: ast.AST) -> str:
    if isinstance(node, ast.Call):
        func = node.func
        return func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
    return ""


def _keyword(call: ast.Call, name: str, position: int | None = None) -> ast.expr | None:
    for kw in call.keywords:
        if kw.arg == name:
            return kw.value
    if position is not None and len(call.args) > position:
        return call.args[position]
    return None


@dataclass(frozen=True)
class Required:
    """The value of a launch argument without a default: the user must give it."""

    argument: str


class _Evaluator:
    """Launch-time values of expressions: str, number, list, :class:`Required`, or None when only known at
    run time.  Calls of the file's own one-``return`` helper functions are evaluated inline."""

    def __init__(self, where: str, install: Install, tree: ast.Module, names: dict[str, ast.expr],
                 arguments: dict[str, ast.expr | None]) -> None:
        self.where, self.install, self.names, self.arguments = where, install, names, arguments
        self.helpers = {f.name: f for f in tree.body if isinstance(f, ast.FunctionDef)
                        and f.name != "generate_launch_description" and isinstance(f.body[-1], ast.Return)}
        self.share_paths: list[Path] = []

    def fail(self, message: str) -> LaunchCheckError:
        return LaunchCheckError(f"{self.where}: {message}")

    def value(self, node: ast.expr | None) -> object:
        if node is None:
            return None
        if isinstance(node, ast.Constant):
            return node.value
        if isinstance(node, ast.Name):
            return self.value(self.names.get(node.id))
        if isinstance(node, ast.List | ast.Tuple):
            return [self.value(e) for e in node.elts]
        if not isinstance(node, ast.Call):
            return None
        name = _call_name(node)
        if name == "LaunchConfiguration":
            argument = self.argument(node)
            default = self.arguments[argument]
            return Required(argument) if default is None else self.value(default)
        if name == "FindPackageShare":
            package = self.value(node.args[0])
            if package != PACKAGE:
                raise self.fail(f"FindPackageShare({package!r}): only {PACKAGE}'s share can be checked")
            return str(self.install.share)
        if name == "PathJoinSubstitution":
            return self._join(node)
        if name == "ParameterValue":
            return self.value(node.args[0])
        if name in self.helpers:
            return self._inline(self.helpers[name], node)
        return None  # PythonExpression, EnvironmentVariable, ...: run-time values

    def _inline(self, func: ast.FunctionDef, call: ast.Call) -> object:
        bound = dict(zip((a.arg for a in func.args.args), call.args))
        saved, self.names = self.names, {**self.names, **bound}
        try:
            return self.value(func.body[-1].value)  # type: ignore[attr-defined]
        finally:
            self.names = saved

    def argument(self, call: ast.Call) -> str:
        name = self.value(call.args[0])
        if name not in self.arguments:
            raise self.fail(f"LaunchConfiguration({name!r}) has no DeclareLaunchArgument")
        return str(name)

    def _join(self, call: ast.Call) -> str | None:
        parts = self.value(call.args[0])
        if not isinstance(parts, list) or any(not isinstance(p, str) for p in parts):
            return None
        path = Path(*parts)
        if path.is_relative_to(self.install.share):
            if not path.exists():
                relative = path.relative_to(self.install.share)
                raise self.fail(f"{relative} does not exist in {self.install.share}")
            self.share_paths.append(path)
        return str(path)


def _function(tree: ast.Module, where: str) -> ast.FunctionDef:
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and node.name == "generate_launch_description":
            return node
    raise LaunchCheckError(f"{where}: no generate_launch_description()")


def _arguments(func: ast.FunctionDef, where: str) -> dict[str, ast.expr | None]:
    arguments: dict[str, ast.expr | None] = {}
    for node in ast.walk(func):
        if _call_name(node) == "DeclareLaunchArgument":
            name_node = _keyword(node, "name", 0)  # type: ignore[arg-type]
            if not isinstance(name_node, ast.Constant):
                raise LaunchCheckError(f"{where}: a DeclareLaunchArgument has no literal name")
            if name_node.value in arguments:
                raise LaunchCheckError(f"{where}: argument {name_node.value!r} is declared twice")
            arguments[name_node.value] = _keyword(node, "default_value")  # type: ignore[arg-type]
    return arguments


def check_launch_file(path: Path, install: Install) -> LaunchSummary:
    """Resolve every name ``path`` gives against ``install``; raise :class:`LaunchCheckError` if one fails."""
    where = path.name
    tree = ast.parse(path.read_text(), filename=str(path))
    func = _function(tree, where)
    names = {t.id: n.value for n in ast.walk(func) if isinstance(n, ast.Assign)
             for t in n.targets if isinstance(t, ast.Name)}
    summary = LaunchSummary(arguments=_arguments(func, where))
    ev = _Evaluator(where, install, tree, names, summary.arguments)
    for node in ast.walk(func):  # every LaunchConfiguration and share path, wherever it is used
        if _call_name(node) in ("LaunchConfiguration", "PathJoinSubstitution", *ev.helpers):
            ev.value(node)  # type: ignore[arg-type]
    scripts = _console_scripts(install)
    for node in ast.walk(func):
        if _call_name(node) == "Node":
            executable, inline = _check_node(node, ev, scripts)  # type: ignore[arg-type]
            summary.executables.append(executable)
            summary.inline_parameters[executable] = inline
    summary.share_paths = sorted(set(ev.share_paths))
    return summary


def _check_node(call: ast.Call, ev: _Evaluator, scripts: dict[str, str]) -> tuple[str, set[str]]:
    """Check one ``Node(...)``; return its executable and the keys of its inline parameters."""
    package, executable = ev.value(_keyword(call, "package")), ev.value(_keyword(call, "executable"))
    if package != PACKAGE:
        raise ev.fail(f"Node package {package!r} is not {PACKAGE}")
    script = ev.install.lib / str(executable)
    if executable not in scripts or not (script.is_file() and os.access(script, os.X_OK)):
        raise ev.fail(f"executable {executable!r} is not a console script in {ev.install.lib}")
    node_name = str(ev.value(_keyword(call, "name")) or executable)
    from_files: dict[str, object] = {}
    inline: dict[str, ast.expr] = {}
    params = _keyword(call, "parameters")
    for element in params.elts if isinstance(params, ast.List) else []:
        if isinstance(element, ast.Dict):
            inline.update({str(ev.value(k)): v for k, v in zip(element.keys, element.values) if k})
            continue
        entry = ev.value(element)
        if isinstance(entry, str):  # a params file (None: only known at run time)
            from_files.update(_params_file_section(ev, Path(entry), node_name))
    declared = declared_parameters(ev.install, scripts[str(executable)])
    unknown = sorted(k for k in (*from_files, *inline) if k not in declared)
    if unknown:
        raise ev.fail(f"parameter(s) {unknown} are not declared by {executable}")
    for key, value in from_files.items():
        if declared[key] is not None and type(value) is not declared[key]:
            raise ev.fail(f"params file value {key}: {value!r} is a {type(value).__name__}, but "
                          f"{executable} declares it as {declared[key].__name__}")  # type: ignore[union-attr]
    for key, expr in inline.items():
        _check_type(ev, str(executable), key, expr, declared[key])
    _check_remaps(call, ev)
    if executable == "ompn_node":
        _check_checkpoint(ev, from_files, inline)
    return str(executable), set(inline)


def _check_type(ev: _Evaluator, executable: str, key: str, expr: ast.expr, declared: type | None) -> None:
    """A parameter must reach the node with its declared type (rclpy rejects a changed type)."""
    if _call_name(expr) == "LaunchConfiguration" and ev.value(expr) == "":
        # launch_ros parses a bare substitution's text as YAML, and '' (null) is no parameter value
        raise ev.fail(f"parameter {key!r} gets the bare default '' (YAML null): wrap it in "
                      "ParameterValue(..., value_type=str)")
    if _call_name(expr) == "ParameterValue":
        given = VALUE_TYPES.get(getattr(_keyword(expr, "value_type"), "id", ""))  # type: ignore[arg-type]
    else:
        given = _literal_type(expr)
    if declared is not None and given is not None and given is not declared:
        raise ev.fail(f"parameter {key!r} is passed as {given.__name__}, but {executable} declares it "
                      f"as {declared.__name__}")


def _params_file_section(ev: _Evaluator, path: Path, node_name: str) -> dict[str, object]:
    if not path.is_file():
        raise ev.fail(f"params file {path} does not exist")
    data = yaml.safe_load(path.read_text()) or {}
    section: dict[str, object] = {}
    for key, value in data.items():
        if key in ("/**", node_name, f"/**/{node_name}", f"/{node_name}"):
            section.update((value or {}).get("ros__parameters", {}))
    return section


def _check_remaps(call: ast.Call, ev: _Evaluator) -> None:
    topics = layout_topics(ev.install)
    for pair in ev.value(_keyword(call, "remappings")) or []:  # type: ignore[union-attr]
        source = pair[0] if isinstance(pair, list) else None
        if source not in topics:
            raise ev.fail(f"remaps {source!r}, which is no topic of ompn_ros/layout.py")


def _check_checkpoint(ev: _Evaluator, from_files: dict[str, object], inline: dict[str, ast.expr]) -> None:
    checkpoint = ev.value(inline["checkpoint"]) if "checkpoint" in inline else from_files.get("checkpoint")
    if isinstance(checkpoint, Required):
        return  # the user names the checkpoint
    if checkpoint:
        path = Path(str(checkpoint))
        if not ((path / "config.json").is_file() or (path / "ensemble.json").is_file()):
            raise ev.fail(f"checkpoint {checkpoint!r} does not resolve to a checkpoint directory")
        return
    domain = ev.value(inline["domain"]) if "domain" in inline else from_files.get("domain")
    shipped = ev.install.site / "ompn_ros" / "checkpoints" / str(domain or "")
    if not domain or not (shipped / "config.json").is_file() or not (shipped / "model.safetensors").is_file():
        raise ev.fail(f"ompn_node gets no checkpoint: checkpoint is '' and domain {domain!r} has no shipped "
                      f"checkpoint in {shipped.parent}")


# --- tests -----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def install(tmp_path_factory: pytest.TempPathFactory) -> Install:
    """A fresh `colcon build` of this package."""
    work = tmp_path_factory.mktemp("colcon_launch")
    colcon = VENV_BIN / "colcon"
    if not colcon.exists():
        pytest.fail("colcon is not installed in the venv; install requirements-dev.txt")
    env = {**os.environ, "PATH": f"{VENV_BIN}:{os.environ.get('PATH', '')}"}
    result = subprocess.run(
        [str(colcon), "build", "--base-paths", str(ROOT), "--build-base", str(work / "build"),
         "--install-base", str(work / "install")],
        cwd=work, env=env, capture_output=True, text=True, timeout=240,
    )
    assert result.returncode == 0, f"colcon build failed:\n{result.stdout}\n{result.stderr}"
    return Install(work / "install")


def test_every_launch_file_is_installed(install: Install):
    shipped = sorted(p.name for p in (ROOT / "launch").glob("*.launch.py"))
    assert shipped == sorted(LAUNCH_FILES)
    assert sorted(p.name for p in (install.share / "launch").glob("*.launch.py")) == shipped


@pytest.mark.parametrize("name", LAUNCH_FILES)
def test_launch_file_resolves_in_the_install_space(install: Install, name: str):
    summary = check_launch_file(install.share / "launch" / name, install)
    assert summary.share_paths, "the launch file uses no shipped params file"
    assert {"namespace", "use_sim_time", "params_file"} <= set(summary.arguments)


def test_sim_launch_files_start_sim_node_and_recorder(install: Install):
    for domain in ("dial", "craft"):
        summary = check_launch_file(install.share / "launch" / f"{domain}_sim.launch.py", install)
        assert sorted(summary.executables) == sorted([f"{domain}_sim", "ompn_node", "bag_recorder"])
        assert {"record", "bag"} <= set(summary.arguments)
        assert install.share / "config" / f"ompn_node_{domain}.yaml" in summary.share_paths


def test_node_launch_file_requires_the_checkpoint(install: Install):
    summary = check_launch_file(install.share / "launch" / "ompn_node.launch.py", install)
    assert summary.executables == ["ompn_node"]
    assert summary.arguments["checkpoint"] is None  # no default: `checkpoint:=...` is required
    assert {"use_sim_time", "checkpoint"} <= summary.inline_parameters["ompn_node"]
    assert {"obs_topic", "joint_states_topic"} <= set(summary.arguments)


BROKEN = [
    ("dial_sim.launch.py", 'executable="dial_sim"', 'executable="dial_simulator"',
     "executable 'dial_simulator' is not a console script"),
    ("dial_sim.launch.py", '"ompn_node_dial.yaml"', '"ompn_node_dail.yaml"',
     "config/ompn_node_dail.yaml does not exist"),
    ("dial_sim.launch.py", '"wait_topics": ', '"wait_topic": ',
     r"\['wait_topic'\] are not declared by dial_sim"),
    ("craft_sim.launch.py", '_text("bag")', '_text("bags")',
     "LaunchConfiguration\\('bags'\\) has no DeclareLaunchArgument"),
    ("craft_sim.launch.py", '"ompn_node_craft.yaml"', '"ompn_node.yaml"', "ompn_node gets no checkpoint"),
    ("craft_sim.launch.py", '"checkpoint", default_value=""', '"checkpoint", default_value="/no/such/ckpt"',
     "checkpoint '/no/such/ckpt' does not resolve"),
    ("ompn_node.launch.py", '("observation", ', '("observations", ', "remaps 'observations'"),
    ("ompn_node.launch.py", 'package="ompn_ros"', 'package="ompn_ros2"', "Node package 'ompn_ros2'"),
    ("dial_sim.launch.py", '"output": _text("bag")', '"output": LaunchConfiguration("bag")',
     "parameter 'output' gets the bare default ''"),
    ("dial_sim.launch.py", '("rate"), value_type=float', '("rate"), value_type=int',
     "parameter 'rate' is passed as int, but dial_sim declares it as float"),
    ("craft_sim.launch.py", '"wait_topics": ["observation"]', '"wait_topics": "observation"',
     "parameter 'wait_topics' is passed as str, but craft_sim declares it as list"),
]


@pytest.mark.parametrize(("name", "old", "new", "error"), BROKEN, ids=[b[3][:30] for b in BROKEN])
def test_a_broken_name_fails_the_check(install: Install, tmp_path: Path, name: str, old: str, new: str,
                                       error: str):
    text = (install.share / "launch" / name).read_text()
    assert old in text, f"{name} no longer contains {old!r}: update this test"
    broken = tmp_path / name
    broken.write_text(text.replace(old, new))
    with pytest.raises(LaunchCheckError, match=error):
        check_launch_file(broken, install)


@pytest.mark.parametrize(("old", "new", "error"), [
    ("detector_high:", "detector_hi:", r"\['detector_hi'\] are not declared by ompn_node"),
    ("detector_high: 0.1", "detector_high: 1",
     "detector_high: 1 is a int, but ompn_node declares it as float"),
])
def test_a_broken_params_file_fails_the_check(install: Install, tmp_path: Path, old: str, new: str,
                                              error: str):
    params = tmp_path / "params.yaml"
    text = (install.share / "config" / "ompn_node_dial.yaml").read_text()
    assert old in text
    params.write_text(text.replace(old, new))
    launch = (install.share / "launch" / "dial_sim.launch.py").read_text()
    reference = 'PathJoinSubstitution([share, "config", "ompn_node_dial.yaml"])'
    assert reference in launch
    broken = tmp_path / "dial_sim.launch.py"
    broken.write_text(launch.replace(reference, repr(str(params))))
    with pytest.raises(LaunchCheckError, match=error):
        check_launch_file(broken, install)
