"""What ``ompn_segment`` sets up before it replays or tunes: the device, the checkpoint's stepper, the
episodes and the detector settings; and the constants its options offer (devices, the 'hsmm'
detector's lag and delay budget, the tuning objectives).

The replay itself is :mod:`ompn_ros.app.replay`, many bags :mod:`ompn_ros.app.batch`, the tuning
:mod:`ompn_ros.app.detector_tuning`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ompn_ros.app.errors import ReplayError
from ompn_ros.detect.defaults import DEFAULT_OBJECTIVE as DEFAULT_OBJECTIVE  # --objective per domain
from ompn_ros.detect.defaults import DURATION_DELAY as DURATION_DELAY  # the default --max-delay
from ompn_ros.detect.defaults import DURATION_LAG as DURATION_LAG  # the default --lag
from ompn_ros.detect.defaults import OBJECTIVES as OBJECTIVES  # the choices of --objective
from ompn_ros.detect.online import MAX_LAG as MAX_LAG  # the largest --lag
from ompn_ros.train.device import DEVICES as DEVICES  # the choices of --device

if TYPE_CHECKING:  # the rest loads when ompn_segment runs, not for --help (torch: seconds)
    from ompn_ros.data.episode import Episode
    from ompn_ros.data.reader import OnError, ReadResult
    from ompn_ros.detect.settings import DetectorSettings


def replay_device(name: str) -> str:
    """The device ``--device name`` replays on ('cpu' or 'cuda'); ``auto`` is the CPU (batch 1)."""
    from ompn_ros.train.device import resolve_device

    return "cpu" if name == "auto" else resolve_device(name, "--device").type


def load_stepper(checkpoint: str, device: str) -> Any:
    """The stepper of ``checkpoint`` on ``device``: the compiled kernel on the CPU, the policy's torch
    module on 'cuda'; a bad checkpoint is a :class:`ReplayError` naming ``--checkpoint``."""
    from ompn_ros.model.errors import CheckpointError
    from ompn_ros.model.load import stepper_from_checkpoint

    try:
        return stepper_from_checkpoint(checkpoint, "jit" if device == "cpu" else "torch", device)
    except CheckpointError as exc:
        raise ReplayError(f"--checkpoint: {exc}") from exc


def load_episodes(
    bag: str | None, reader_config: str | None, domain: str | None, on_error: OnError, generate: int,
    seed: int, checkpoint: str | None = None,
) -> tuple[list[Episode], ReadResult | None]:
    """The episodes of ``bag`` (with what the reader kept and dropped; ``final_observation: auto`` as
    ``checkpoint`` was trained), else ``generate`` fresh expert episodes of ``domain`` from ``seed`` (no
    read result)."""
    from ompn_ros.app import replay

    if bag:
        result = replay.read_bag_episodes(bag, reader_config, domain, on_error, checkpoint)
        return list(result.episodes), result
    if generate:
        return replay.generate_episodes(domain or "", generate, seed), None
    raise ReplayError("give --bag PATH or --generate N --domain D")


def detector_settings(checkpoint: str, detector_config: str | None) -> tuple[DetectorSettings, str]:
    """The detector settings a replay runs with (``--detector-config``, else the checkpoint's own, else the
    defaults) and the line saying which they are (:func:`ompn_ros.detect.settings.resolve_detector`)."""
    from ompn_ros.detect.params_file import load_detector_yaml
    from ompn_ros.detect.settings import resolve_detector

    explicit = load_detector_yaml(detector_config) if detector_config else None
    return resolve_detector(checkpoint, explicit, f"--detector-config {detector_config}")
