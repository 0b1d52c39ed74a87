"""Install metadata covers what the code imports: package.xml (rosdep keys or a pip comment) and
requirements.txt (pinned runtime deps), with the development tools in requirements-dev.txt only.

The imports are read from the sources (AST, no import), so a new third-party import without a
declaration fails here with the file that imports it.
"""

from __future__ import annotations

import ast
import re
import sys
import xml.etree.ElementTree as ET
from importlib import metadata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
OWN = frozenset({"ompn_ros", "sim_nodes"})
# Standard library from a later Python than this one (imported behind a version check).
LATER_STDLIB = frozenset({"compression"})  # compression.zstd, Python 3.14

# ROS 2 packages: from the ROS installation, declared in package.xml under their own name.
ROS = frozenset({
    "rclpy", "rcl_interfaces", "builtin_interfaces", "std_msgs", "std_srvs", "sensor_msgs", "geometry_msgs",
    "diagnostic_msgs", "lifecycle_msgs", "rosgraph_msgs", "ament_index_python", "launch", "launch_ros",
    "ompn_interfaces",  # this repository's interface package (ompn_interfaces/): colcon or make setup
})
# Python packages: import name -> (rosdep key, or None when only pip has it; pip distribution).
PYTHON: dict[str, tuple[str | None, str]] = {
    "numpy": ("python3-numpy", "numpy"),
    "yaml": ("python3-yaml", "PyYAML"),
    "scipy": ("python3-scipy", "scipy"),
    "matplotlib": ("python3-matplotlib", "matplotlib"),
    "PIL": ("python3-pil", "pillow"),
    "tqdm": ("python3-tqdm", "tqdm"),
    "torch": (None, "torch"),
    "numba": (None, "numba"),
    "llvmlite": (None, "llvmlite"),
    "safetensors": (None, "safetensors"),
    "rosbags": (None, "rosbags"),
    "backports": (None, "backports.zstd"),
    "mcap": (None, "mcap"),
    "mujoco": (None, "mujoco"),
    "dm_control": (None, "dm_control"),
    "gymnasium": (None, "gymnasium"),
    "tensorboard": (None, "tensorboard"),
    "_ruamel_yaml": (None, "ruamel.yaml.clib"),
}
# Imported only inside ``try: ... except ImportError``: a feature that is there when the user has the
# package, never a dependency.
OPTIONAL = {
    "pyarrow": "ompn_segment --bags also writes segments.parquet (experiments/batch_table.py); LeRobot "
               "datasets (--dataset) are read and written with it (data/lerobot/layout.py)",
}
# Needed at run time without an import statement in our sources.
USED_WITHOUT_IMPORT = {
    "scipy": "the BLAS behind numba's np.dot in the compiled streaming step",
    "dm_control": "importlib.resources.files('dm_control'): the JACO model files of the Dial scene",
    "tensorboard": "torch.utils.tensorboard, when train.tensorboard is true",
    "PIL": "matplotlib's image writer (PNG figures)",
    "_ruamel_yaml": "the C parser rosbags' reader uses for a bag's metadata.yaml when it is installed",
}
DEV_TOOLS = ("pytest", "pytest-timeout", "hypothesis", "mcap-ros2-support", "ruff", "mypy",
             "colcon-common-extensions", "lerobot-dataset")


def third_party_imports(*roots: Path) -> dict[str, str]:
    """Top-level module name -> first file importing it, for every non-stdlib, non-own import."""
    found: dict[str, str] = {}
    for root in roots:
        for path in sorted(root.rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split(".")[0]
                    if top not in sys.stdlib_module_names and top not in OWN | LATER_STDLIB:
                        found.setdefault(top, str(path.relative_to(ROOT)))
    return found


def _normalise(dist: str) -> str:
    return re.sub(r"[-_.]+", "-", dist).lower()


def package_xml_declarations(text: str) -> tuple[set[str], set[str]]:
    """(keys of the run-time depend tags, pip packages named by ``pip: <name>`` comment lines)."""
    root = ET.fromstring(text, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    keys = {(e.text or "").strip() for e in root if e.tag in ("depend", "exec_depend")}
    pip = set()
    for element in root.iter(ET.Comment):
        pip |= {_normalise(m) for m in re.findall(r"^\s*pip:\s*([A-Za-z0-9_.\-]+)", element.text or "", re.M)}
    return keys, pip


def missing_from_package_xml(modules: dict[str, str], text: str) -> list[str]:
    """One line per module whose dependency package.xml does not declare."""
    keys, pip = package_xml_declarations(text)
    missing = []
    for module, where in sorted(modules.items()):
        if module in ROS:
            ok, wanted = module in keys, f"<exec_depend>{module}</exec_depend>"
        else:
            rosdep, dist = PYTHON[module]
            ok = rosdep in keys if rosdep else _normalise(dist) in pip
            wanted = f"<exec_depend>{rosdep}</exec_depend>" if rosdep else f"a comment line 'pip: {dist}'"
        if not ok:
            missing.append(f"{module} (used by {where}): package.xml needs {wanted}")
    return missing


def requirement_pins(text: str) -> dict[str, str]:
    """Normalised distribution -> pinned version of a requirements file (``-r`` lines skipped)."""
    pins = {}
    for raw in text.splitlines():
        line = raw.split("#")[0].strip()
        if not line or line.startswith("-"):
            continue
        match = re.fullmatch(r"([A-Za-z0-9_.\-]+)==([A-Za-z0-9_.+\-]+)", line)
        if match is None:
            raise AssertionError(f"requirement '{line}' is not pinned as name==version")
        pins[_normalise(match.group(1))] = match.group(2)
    return pins


def missing_from_requirements(modules: dict[str, str], text: str) -> list[str]:
    """One line per non-ROS module whose pip distribution is not pinned in ``text``."""
    pins = requirement_pins(text)
    return [f"{module} (used by {where}): requirements.txt needs {PYTHON[module][1]}==<version>"
            for module, where in sorted(modules.items())
            if module not in ROS and _normalise(PYTHON[module][1]) not in pins]


@pytest.fixture(scope="module")
def used() -> dict[str, str]:
    modules = third_party_imports(ROOT / "ompn_ros", ROOT / "sim_nodes", ROOT / "launch")
    assert set(OPTIONAL) <= set(modules), f"optional imports no longer used: {set(OPTIONAL) - set(modules)}"
    modules = {m: where for m, where in modules.items() if m not in OPTIONAL}
    modules.update({m: "(no import statement)" for m in USED_WITHOUT_IMPORT})
    return modules


def test_every_third_party_import_has_a_known_dependency(used: dict[str, str]):
    unknown = sorted(f"{m} ({where})" for m, where in used.items() if m not in ROS and m not in PYTHON)
    assert not unknown, f"imports without a dependency entry (add them to package.xml, requirements.txt " \
                        f"and this test's table): {unknown}"
    assert {"torch", "numba", "rclpy", "launch_ros"} <= set(used)  # the scan sees real imports


def test_package_xml_declares_every_runtime_dependency(used: dict[str, str]):
    missing = missing_from_package_xml(used, (ROOT / "package.xml").read_text())
    assert not missing, "\n".join(missing)


def test_requirements_txt_pins_every_runtime_dependency_and_nothing_else(used: dict[str, str]):
    text = (ROOT / "requirements.txt").read_text()
    missing = missing_from_requirements(used, text)
    assert not missing, "\n".join(missing)
    pins = set(requirement_pins(text))
    expected = {_normalise(PYTHON[m][1]) for m in used if m not in ROS}
    assert pins == expected, f"not used by the code: {sorted(pins - expected)}"
    assert not pins & {_normalise(t) for t in DEV_TOOLS}
    assert re.search(r"^#.*CPU", text, re.M | re.I) and "torch==" in text


def test_requirements_dev_adds_the_tools_on_top_of_the_runtime():
    text = (ROOT / "requirements-dev.txt").read_text()
    assert re.search(r"^-r requirements\.txt\s*$", text, re.M)
    pins = requirement_pins(text)
    assert set(pins) == {_normalise(t) for t in DEV_TOOLS}


@pytest.mark.parametrize("name", ["requirements.txt", "requirements-dev.txt"])
def test_pins_are_the_versions_installed_here(name: str):
    """The pins are what the test suite runs with (local labels such as +cpu aside)."""
    for dist, pinned in requirement_pins((ROOT / name).read_text()).items():
        installed = metadata.version(dist).split("+")[0]
        assert installed == pinned, f"{name}: {dist}=={pinned}, installed {installed}"


def test_the_checks_name_what_is_missing():
    modules = {"torch": "ompn_ros/a.py", "numpy": "ompn_ros/b.py", "rclpy": "ompn_ros/nodes/c.py"}
    xml = ("<package><exec_depend>python3-numpy</exec_depend><!-- pip: torchvision -->"
           "<test_depend>rclpy</test_depend></package>")
    assert missing_from_package_xml(modules, xml) == [
        "rclpy (used by ompn_ros/nodes/c.py): package.xml needs <exec_depend>rclpy</exec_depend>",
        "torch (used by ompn_ros/a.py): package.xml needs a comment line 'pip: torch'",
    ]
    fixed = xml.replace("torchvision", "torch").replace("test_", "exec_")
    assert missing_from_package_xml(modules, fixed) == []
    assert missing_from_requirements(modules, "numpy==2.4.6\n# torch==2.13.0\n") == [
        "torch (used by ompn_ros/a.py): requirements.txt needs torch==<version>"
    ]
    with pytest.raises(AssertionError, match="'torch>=2' is not pinned"):
        requirement_pins("torch>=2\n")
