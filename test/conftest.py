"""Test-wide setup: DDS containment before anything can import rclpy."""

from __future__ import annotations

import os
import re
import sys

# Fast DDS must stay on loopback and shared memory (config/fastdds_loopback.xml, see
# ompn_ros.ros.containment: the profile, ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT so that rmw applies
# it untouched, no static peers), and concurrent runs must not see each other (a random
# ROS_DOMAIN_ID). This runs before any test module imports rclpy, so a bare `pytest` is contained.
from ompn_ros.ros import containment

containment.contain(os.environ)
os.environ.setdefault("MUJOCO_GL", "egl")

import pytest  # noqa: E402 (after the containment, before anything imports rclpy)

# The tests live in one folder per room (test/README.md); what they share lives here at test/, importable
# from every room whatever pytest's import mode.
_SUPPORT = os.path.dirname(os.path.abspath(__file__))
if _SUPPORT not in sys.path:
    sys.path.insert(0, _SUPPORT)


@pytest.fixture(autouse=True)
def _dds_stays_on_loopback():
    """Fail any test that leaves rclpy in use with the DDS containment undone."""
    yield
    if "rclpy" in sys.modules:
        found = containment.problems(os.environ)
        assert not found, f"rclpy is in use but DDS is not contained: {'; '.join(found)}"


@pytest.fixture(scope="module")
def ctx():
    """An rclpy context per test module, for the node tests that run the node in process."""
    import rclpy

    context = rclpy.context.Context()
    rclpy.init(context=context)
    yield context
    rclpy.try_shutdown(context=context)


@pytest.fixture
def ros_env() -> dict[str, str]:
    """Environment for child processes that start rclpy (keeps LD_LIBRARY_PATH and containment)."""
    env = dict(os.environ)
    containment.contain(env)
    env["PYTHONUNBUFFERED"] = "1"
    return env


@pytest.fixture(scope="session")
def synthetic_checkpoint(tmp_path_factory: pytest.TempPathFactory):
    """A small OMPN trained on the synthetic corridor task (~10 s), shared by the whole session."""
    from ompn_ros.model.config import OMPNConfig
    from ompn_ros.train import synthetic, trainer
    from ompn_ros.train.config import TrainConfig

    path = tmp_path_factory.getbasetemp() / "synthetic_discrete_ckpt"
    if not (path / "best").is_dir():
        obs_dim, action_type, action_dim, _ = synthetic.synthetic_spec("discrete")
        cfg = OMPNConfig(obs_dim=obs_dim, action_type=action_type, action_dim=action_dim,
                         n_slots=3, slot_size=32)
        train_cfg = TrainConfig(iterations=120, batch_size=32, eval_every=40, out_dir=str(path),
                                lr=3e-3, progress=False)
        trainer.train(synthetic.make_dataset("discrete", 64, seed=0), cfg, train_cfg)
    return path / "best"


# --- test categories ------------------------------------------------------------------------------
# `ros`: starts rclpy (a DDS participant, often a second process); `integration`: builds, trains or
# runs other programs. The rest is the fast core: `make test-fast` runs it in well under a minute.
_INTEGRATION_HINTS = ("subprocess", "synthetic_checkpoint", "trainer.train", "torchrun", "colcon")


_SHARED_IMPORT = re.compile(r"^\s*(?:from|import) (\w+)", re.MULTILINE)


def _categories(path: str) -> set[str]:
    """The categories of a test module, from its source and that of the shared helpers it imports
    (a helper that starts a process makes its callers integration tests)."""
    with open(path, encoding="utf-8") as handle:
        source = handle.read()
    for name in set(_SHARED_IMPORT.findall(source)):
        shared = os.path.join(_SUPPORT, f"{name}.py")
        if name != "conftest" and os.path.isfile(shared):
            with open(shared, encoding="utf-8") as handle:
                source += handle.read()
    found = set()
    if "rclpy" in source or "ros_env" in source:
        found.add("ros")
    if any(hint in source for hint in _INTEGRATION_HINTS):
        found.add("integration")
    return found


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    cache: dict[str, set[str]] = {}
    for item in items:
        path = str(item.path)
        if path not in cache:
            cache[path] = _categories(path)
        for name in sorted(cache[path]):
            item.add_marker(getattr(pytest.mark, name))
