"""The launch files resolve in a colcon install space, checked without the ``launch`` package.

Each installed ``share/ompn_ros/launch/*.launch.py`` is run against stand-ins of the ``launch`` and
``launch_ros`` classes that record what they were given (the sim launch files build their description
with the installed ``ompn_ros.ros.launch_sim``).  Its launch-time values are then resolved
(``DeclareLaunchArgument`` defaults, ``LaunchConfiguration``, ``FindPackageShare`` +
``PathJoinSubstitution``).  A launch file passes when

* every ``LaunchConfiguration`` names a declared argument, and arguments are declared once;
* every package-share path it joins exists in the install space;
* every ``Node`` runs an ``ompn_ros`` console script found in ``lib/ompn_ros``;
* every parameter key it passes (inline dicts and the node's section of every params file) is declared
  by that node's source in the install space (``declare_parameter`` / ``ParamSpec``, read as an AST),
  or is ``use_sim_time``, and reaches the node with the type of the declared default
  (``ParameterValue`` ``value_type``, a literal, or the YAML value; a bare substitution of '' would be
  YAML null);
* every remapped name is a topic of ``ompn_ros/layout.py``;
* ``ompn_node`` gets a checkpoint: a required argument, an installed checkpoint directory, or the
  shipped checkpoint of the ``domain`` its params file sets.

The negative tests break one name at a time in a copy (of a launch file, or of the builder module)
and expect the matching one-line error.
"""

from __future__ import annotations

import ast
import configparser
import importlib.util
import os
import runpy
import subprocess
import sys
import types
from dataclasses import dataclass, field
from pathlib import Path
from unittest import mock

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
VENV_BIN = Path(sys.executable).parent
PACKAGE = "ompn_ros"
BUILTIN_PARAMETERS: dict[str, type | None] = {"use_sim_time": bool}  # declared by every rclpy node
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

    arguments: dict[str, object] = field(default_factory=dict)  # name -> default (None: required)
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


# --- running the launch file against stand-ins of the launch packages -----------------------------
STAND_INS = {
    "launch": ("LaunchDescription",),
    "launch.actions": ("DeclareLaunchArgument", "GroupAction", "IncludeLaunchDescription"),
    "launch.conditions": ("IfCondition", "UnlessCondition"),
    "launch.substitutions": ("LaunchConfiguration", "PathJoinSubstitution", "PythonExpression",
                             "EnvironmentVariable", "TextSubstitution"),
    "launch_ros": (),
    "launch_ros.actions": ("Node",),
    "launch_ros.parameter_descriptions": ("ParameterValue",),
    "launch_ros.substitutions": ("FindPackageShare",),
}
BUILDER = "ompn_ros.ros.launch_sim"  # the module the sim launch files build their description with


@dataclass
class Made:
    """What a launch file made of one stand-in class: its name and the arguments it was given."""

    kind: str
    args: tuple[object, ...]
    kwargs: dict[str, object]

    def arg(self, name: str, position: int | None = None) -> object:
        if name in self.kwargs:
            return self.kwargs[name]
        return self.args[position] if position is not None and len(self.args) > position else None


@dataclass(frozen=True)
class Required:
    """The value of a launch argument without a default: the user must give it."""

    argument: str


def _stand_in_modules(made: list[Made]) -> dict[str, types.ModuleType]:
    modules = {}
    for module, kinds in STAND_INS.items():
        stand_in = types.ModuleType(module)
        for kind in kinds:
            def make(*args: object, _kind: str = kind, **kwargs: object) -> Made:
                made.append(Made(_kind, args, kwargs))
                return made[-1]

            setattr(stand_in, kind, make)
        modules[module] = stand_in
    return modules


def run_launch_file(path: Path, install: Install, builder: Path | None = None) -> tuple[Made, list[Made]]:
    """``generate_launch_description()`` of ``path``, with the installed :data:`BUILDER` (or ``builder``)
    and the launch packages' stand-ins: the description and everything the file made."""
    made: list[Made] = []
    builder = builder or _module_file(install, BUILDER)
    if not builder.is_file():
        raise LaunchCheckError(f"{path.name}: {BUILDER} is not installed ({builder})")
    spec = importlib.util.spec_from_file_location(BUILDER, builder)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    with mock.patch.dict(sys.modules, {**_stand_in_modules(made), BUILDER: module}):
        spec.loader.exec_module(module)
        try:
            description = runpy.run_path(str(path))["generate_launch_description"]()
        except KeyError as exc:
            raise LaunchCheckError(f"{path.name}: no generate_launch_description()") from exc
    if not isinstance(description, Made) or description.kind != "LaunchDescription":
        raise LaunchCheckError(f"{path.name}: generate_launch_description() returns no LaunchDescription")
    return description, made


class _Resolver:
    """Launch-time values: str, number, list, :class:`Required`, or None when only known at run time."""

    def __init__(self, where: str, install: Install, arguments: dict[str, object]) -> None:
        self.where, self.install, self.arguments = where, install, arguments
        self.share_paths: list[Path] = []

    def fail(self, message: str) -> LaunchCheckError:
        return LaunchCheckError(f"{self.where}: {message}")

    def value(self, item: object) -> object:
        if not isinstance(item, Made):
            return [self.value(e) for e in item] if isinstance(item, list | tuple) else item
        if item.kind == "LaunchConfiguration":
            name = self.argument(item)
            default = self.arguments[name]
            return Required(name) if default is None else self.value(default)
        if item.kind == "FindPackageShare":
            if item.args[0] != PACKAGE:
                raise self.fail(f"FindPackageShare({item.args[0]!r}): only {PACKAGE}'s share can be checked")
            return str(self.install.share)
        if item.kind == "PathJoinSubstitution":
            return self._join(item)
        if item.kind == "ParameterValue":
            return self.value(item.args[0])
        return None  # PythonExpression, EnvironmentVariable, ...: run-time values

    def argument(self, made: Made) -> str:
        name = str(made.arg("variable_name", 0))
        if name not in self.arguments:
            raise self.fail(f"LaunchConfiguration({name!r}) has no DeclareLaunchArgument")
        return name

    def _join(self, made: Made) -> str | None:
        parts = [self.value(p) for p in made.args[0]]  # type: ignore[union-attr]
        parts = ["".join(p) if isinstance(p, list) and all(isinstance(s, str) for s in p) else p
                 for p in parts]  # a list in a substitution is concatenated
        if any(not isinstance(p, str) for p in parts):
            return None
        path = Path(*parts)  # type: ignore[arg-type]
        if path.is_relative_to(self.install.share):
            if not path.exists():
                relative = path.relative_to(self.install.share)
                raise self.fail(f"{relative} does not exist in {self.install.share}")
            self.share_paths.append(path)
        return str(path)


def _entities(description: Made) -> list[Made]:
    return [e for e in description.args[0] if isinstance(e, Made)]  # type: ignore[union-attr]


def _arguments(description: Made, where: str) -> dict[str, object]:
    arguments: dict[str, object] = {}
    for entity in _entities(description):
        if entity.kind == "DeclareLaunchArgument":
            name = entity.arg("name", 0)
            if not isinstance(name, str):
                raise LaunchCheckError(f"{where}: a DeclareLaunchArgument has no literal name")
            if name in arguments:
                raise LaunchCheckError(f"{where}: argument {name!r} is declared twice")
            arguments[name] = entity.arg("default_value")
    return arguments


def check_launch_file(path: Path, install: Install, builder: Path | None = None) -> LaunchSummary:
    """Resolve every name ``path`` gives against ``install``; raise :class:`LaunchCheckError` if one fails."""
    description, made = run_launch_file(path, install, builder)
    summary = LaunchSummary(arguments=_arguments(description, path.name))
    res = _Resolver(path.name, install, summary.arguments)
    for item in made:  # every LaunchConfiguration and share path, wherever it is used
        if item.kind in ("LaunchConfiguration", "PathJoinSubstitution"):
            res.value(item)
    for default in summary.arguments.values():
        res.value(default)
    scripts = _console_scripts(install)
    for entity in _entities(description):
        if entity.kind == "Node":
            executable, inline = _check_node(entity, res, scripts)
            summary.executables.append(executable)
            summary.inline_parameters[executable] = inline
    summary.share_paths = sorted(set(res.share_paths))
    return summary


def _check_node(node: Made, res: _Resolver, scripts: dict[str, str]) -> tuple[str, set[str]]:
    """Check one ``Node(...)``; return its executable and the keys of its inline parameters."""
    package, executable = res.value(node.arg("package")), res.value(node.arg("executable"))
    if package != PACKAGE:
        raise res.fail(f"Node package {package!r} is not {PACKAGE}")
    script = res.install.lib / str(executable)
    if executable not in scripts or not (script.is_file() and os.access(script, os.X_OK)):
        raise res.fail(f"executable {executable!r} is not a console script in {res.install.lib}")
    node_name = str(res.value(node.arg("name")) or executable)
    from_files: dict[str, object] = {}
    inline: dict[str, object] = {}
    for element in node.arg("parameters") or []:  # type: ignore[attr-defined]
        if isinstance(element, dict):
            inline.update(element)
            continue
        entry = res.value(element)
        if isinstance(entry, str):  # a params file (None: only known at run time)
            from_files.update(_params_file_section(res, Path(entry), node_name))
    declared = declared_parameters(res.install, scripts[str(executable)])
    unknown = sorted(k for k in (*from_files, *inline) if k not in declared)
    if unknown:
        raise res.fail(f"parameter(s) {unknown} are not declared by {executable}")
    for key, value in from_files.items():
        if declared[key] is not None and type(value) is not declared[key]:
            raise res.fail(f"params file value {key}: {value!r} is a {type(value).__name__}, but "
                           f"{executable} declares it as {declared[key].__name__}")  # type: ignore[union-attr]
    for key, given in inline.items():
        _check_type(res, str(executable), key, given, declared[key])
    _check_remaps(node, res)
    if executable == "ompn_node":
        _check_checkpoint(res, from_files, inline)
    return str(executable), set(inline)


def _check_type(res: _Resolver, executable: str, key: str, given: object, declared: type | None) -> None:
    """A parameter must reach the node with its declared type (rclpy rejects a changed type)."""
    if isinstance(given, Made) and given.kind == "LaunchConfiguration" and res.value(given) == "":
        # launch_ros parses a bare substitution's text as YAML, and '' (null) is no parameter value
        raise res.fail(f"parameter {key!r} gets the bare default '' (YAML null): wrap it in "
                       "ParameterValue(..., value_type=str)")
    if isinstance(given, Made):
        kind = given.arg("value_type") if given.kind == "ParameterValue" else None
    else:
        kind = type(given)
    if declared is not None and isinstance(kind, type) and kind is not declared:
        raise res.fail(f"parameter {key!r} is passed as {kind.__name__}, but {executable} declares it "
                       f"as {declared.__name__}")


def _params_file_section(res: _Resolver, path: Path, node_name: str) -> dict[str, object]:
    if not path.is_file():
        raise res.fail(f"params file {path} does not exist")
    data = yaml.safe_load(path.read_text()) or {}
    section: dict[str, object] = {}
    for key, value in data.items():
        if key in ("/**", node_name, f"/**/{node_name}", f"/{node_name}"):
            section.update((value or {}).get("ros__parameters", {}))
    return section


def _check_remaps(node: Made, res: _Resolver) -> None:
    topics = layout_topics(res.install)
    for pair in node.arg("remappings") or []:  # type: ignore[attr-defined]
        source = res.value(pair[0])
        if (source, res.value(pair[1])) == ("/clock", "clock"):  # use_sim_time follows the namespace's sim
            continue
        if source not in topics:
            raise res.fail(f"remaps {source!r}, which is no topic of ompn_ros/layout.py")


def _check_checkpoint(res: _Resolver, from_files: dict[str, object], inline: dict[str, object]) -> None:
    checkpoint = res.value(inline["checkpoint"]) if "checkpoint" in inline else from_files.get("checkpoint")
    if isinstance(checkpoint, Required):
        return  # the user names the checkpoint
    if checkpoint:
        path = Path(str(checkpoint))
        if not ((path / "config.json").is_file() or (path / "ensemble.json").is_file()):
            raise res.fail(f"checkpoint {checkpoint!r} does not resolve to a checkpoint directory")
        return
    domain = res.value(inline["domain"]) if "domain" in inline else from_files.get("domain")
    shipped = res.install.site / "ompn_ros" / "checkpoints" / str(domain or "")
    if not domain or not (shipped / "config.json").is_file() or not (shipped / "model.safetensors").is_file():
        raise res.fail(f"ompn_node gets no checkpoint: checkpoint is '' and domain {domain!r} has no shipped "
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
        assert ("task" in summary.arguments) == (domain == "craft")  # the sim's own argument
        assert ("task" in summary.inline_parameters[f"{domain}_sim"]) == (domain == "craft")


def test_node_launch_file_requires_the_checkpoint(install: Install):
    summary = check_launch_file(install.share / "launch" / "ompn_node.launch.py", install)
    assert summary.executables == ["ompn_node"]
    assert summary.arguments["checkpoint"] is None  # no default: `checkpoint:=...` is required
    assert {"use_sim_time", "checkpoint"} <= summary.inline_parameters["ompn_node"]
    assert {"obs_topic", "joint_states_topic"} <= set(summary.arguments)


BUILT = "ompn_ros/ros/launch_sim.py"  # the builder module the sim launch files call
# (launch file, None = break the launch file itself or BUILT = break the builder, old, new, error)
BROKEN = [
    ("dial_sim.launch.py", None, '"dial", rate=', '"dail", rate=',
     "config/ompn_node_dail.yaml does not exist"),
    ("craft_sim.launch.py", None, '("task", "makebed"', '("tasks", "makebed"',
     r"\['tasks'\] are not declared by craft_sim"),
    ("dial_sim.launch.py", BUILT, 'executable=f"{domain}_sim"', 'executable=f"{domain}_simulator"',
     "executable 'dial_simulator' is not a console script"),
    ("dial_sim.launch.py", BUILT, '"wait_topics": ', '"wait_topic": ',
     r"\['wait_topic'\] are not declared by dial_sim"),
    ("craft_sim.launch.py", BUILT, '_param("bag")', '_param("bags")',
     "LaunchConfiguration\\('bags'\\) has no DeclareLaunchArgument"),
    ("craft_sim.launch.py", BUILT, 'f"ompn_node_{domain}.yaml"', '"ompn_node.yaml"',
     "ompn_node gets no checkpoint"),
    ("craft_sim.launch.py", BUILT, '("checkpoint", "",', '("checkpoint", "/no/such/ckpt",',
     "checkpoint '/no/such/ckpt' does not resolve"),
    ("ompn_node.launch.py", None, '("observation", ', '("observations", ', "remaps 'observations'"),
    ("ompn_node.launch.py", None, 'package="ompn_ros"', 'package="ompn_ros2"', "Node package 'ompn_ros2'"),
    ("dial_sim.launch.py", BUILT, '"output": _param("bag")', '"output": LaunchConfiguration("bag")',
     "parameter 'output' gets the bare default ''"),
    ("dial_sim.launch.py", BUILT, '_param("rate", float)', '_param("rate", int)',
     "parameter 'rate' is passed as int, but dial_sim declares it as float"),
    ("craft_sim.launch.py", BUILT, '"wait_topics": ["observation"]', '"wait_topics": "observation"',
     "parameter 'wait_topics' is passed as str, but craft_sim declares it as list"),
]


@pytest.mark.parametrize(("name", "built", "old", "new", "error"), BROKEN, ids=[b[4][:30] for b in BROKEN])
def test_a_broken_name_fails_the_check(install: Install, tmp_path: Path, name: str, built: str | None,
                                       old: str, new: str, error: str):
    source = install.share / "launch" / name if built is None else install.site / built
    text = source.read_text()
    assert old in text, f"{source.name} no longer contains {old!r}: update this test"
    broken = tmp_path / source.name
    broken.write_text(text.replace(old, new))
    launch = broken if built is None else install.share / "launch" / name
    with pytest.raises(LaunchCheckError, match=error):
        check_launch_file(launch, install, builder=None if built is None else broken)


@pytest.mark.parametrize(("old", "new", "error"), [
    ("domain:", "domian:", r"\['domian'\] are not declared by ompn_node"),
    ("domain: dial", "domain: 1", "domain: 1 is a int, but ompn_node declares it as str"),
])
def test_a_broken_params_file_fails_the_check(install: Install, tmp_path: Path, old: str, new: str,
                                              error: str):
    params = tmp_path / "params.yaml"
    text = (install.share / "config" / "ompn_node_dial.yaml").read_text()
    assert old in text
    params.write_text(text.replace(old, new))
    built = (install.site / BUILT).read_text()
    reference = 'PathJoinSubstitution([FindPackageShare("ompn_ros"), "config", f"ompn_node_{domain}.yaml"])'
    assert reference in built
    broken = tmp_path / "launch_sim.py"
    broken.write_text(built.replace(reference, repr(str(params))))
    with pytest.raises(LaunchCheckError, match=error):
        check_launch_file(install.share / "launch" / "dial_sim.launch.py", install, builder=broken)
