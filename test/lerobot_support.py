"""LeRobot's own dataset library (``lerobot-dataset``, imported as ``ledataset``) for the tests.

:func:`ledataset_or_skip` imports it or skips the test naming why.  ``ledataset`` imports
``torchvision`` at module level (image transforms, video decoding) without declaring it; PyPI serves
only CUDA builds of torchvision for Linux, which do not import next to the CPU torch this project
installs.  Where torchvision cannot be imported, a placeholder module stands in for it: the names
``ledataset`` imports, each raising when called.  The datasets of these tests have no image or video
feature, so no torchvision code would run; a test that reached one fails loudly instead of passing.

:func:`write_dataset` writes episodes as a LeRobot v3.0 dataset with ``ledataset``'s writer
(``LeRobotDataset.create``, ``add_frame``, ``save_episode``, ``finalize``), as another lab would.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import sys
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ompn_ros.data.episode import Episode


def _refuse(name: str) -> Any:
    def call(*args: Any, **kwargs: Any) -> Any:
        raise RuntimeError(f"torchvision placeholder: {name} was called (this test has no images)")
    return call


class _Placeholder(types.ModuleType):
    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return _refuse(f"{self.__name__}.{name}")


def _torchvision_placeholder() -> None:
    importlib.import_module("datasets")  # first: Hugging Face datasets then sees no torchvision
    for name in ("torchvision", "torchvision.transforms", "torchvision.transforms.v2",
                 "torchvision.transforms.v2.functional", "torchvision.io"):
        sys.modules[name] = module = _Placeholder(name)
        module.__spec__ = importlib.machinery.ModuleSpec(name, None)
    sys.modules["torchvision"].transforms = sys.modules["torchvision.transforms"]  # type: ignore[attr-defined]
    sys.modules["torchvision.transforms"].v2 = sys.modules["torchvision.transforms.v2"]  # type: ignore[attr-defined]


def ledataset_or_skip() -> Any:
    """The ``ledataset.datasets.lerobot_dataset`` module, or a skip naming what is missing."""
    try:
        importlib.import_module("torchvision")
    except (ImportError, RuntimeError):  # absent, or a CUDA build beside the CPU torch
        for name in [n for n in sys.modules if n == "torchvision" or n.startswith("torchvision.")]:
            del sys.modules[name]
        _torchvision_placeholder()
    try:
        return importlib.import_module("ledataset.datasets.lerobot_dataset")
    except ImportError as exc:
        pytest.skip(f"LeRobot's dataset library is not importable ({exc}): "
                    "pip install -r requirements-dev.txt (lerobot-dataset)")


def write_dataset(root: Path, episodes: list[Episode], *, fps: int = 25, labels: bool = True,
                  task: str = "demo", file_mb: float | None = None) -> Path:
    """``episodes`` as a LeRobot v3.0 dataset at ``root`` written by LeRobot's own writer.

    Frame ``t`` holds observation row ``t`` and action ``t``; an episode of ``T`` steps gives ``T + 1``
    frames, the last one the final observation with the last action repeated (LeRobot stores an action
    on every frame).  With ``labels`` each frame's ``task`` is its subtask (``"<task> subtask <k>"``), so
    ``task_index`` changes where the subtask does: features of shape ``(1,)`` of one's own cannot be
    written by ``ledataset`` 0.4.4 beside numpy 2.4 (``int()`` of a one-element array), hence no
    discrete actions and no label feature of their own here.  ``file_mb``: LeRobot's cap on a frame
    file's size (``data_files_size_in_mb``), set small to spread the episodes over several files."""
    lerobot = ledataset_or_skip()
    first = episodes[0]
    features: dict[str, Any] = {
        "observation.state": {"dtype": "float32", "shape": (first.observations.shape[1],), "names": None},
        "action": {"dtype": "float32", "shape": (first.actions.shape[1],), "names": None},
    }
    dataset = lerobot.LeRobotDataset.create(repo_id="lab/demo", fps=fps, root=root, features=features,
                                            use_videos=False)
    if file_mb is not None:  # the writer starts a new frame file once a file would pass the cap
        dataset.meta.info["data_files_size_in_mb"] = file_mb
    for ep in episodes:
        for t in range(ep.length + 1):
            step = min(t, ep.length - 1)
            named = labels and ep.subtask is not None
            dataset.add_frame({
                "observation.state": np.asarray(ep.observations[t], np.float32),
                "action": np.asarray(ep.actions[step] if ep.length else np.zeros(first.actions.shape[1]),
                                     np.float32),
                "task": f"{task} subtask {int(ep.subtask[step])}" if named else task,  # type: ignore[index]
            })
        dataset.save_episode()
    dataset.finalize()
    return root


def load_dataset(root: Path) -> Any:
    """The dataset at ``root`` opened by LeRobot's own loader (local files only)."""
    return ledataset_or_skip().LeRobotDataset("lab/demo", root=root)
