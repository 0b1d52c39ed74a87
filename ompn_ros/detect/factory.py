"""The online detector a :class:`~ompn_ros.detect.online.DetectorConfig` names, built from what the
checkpoint holds (the duration model, the boundary head)."""

from __future__ import annotations

from ompn_ros.detect.duration import DurationDetector, DurationModel
from ompn_ros.detect.errors import BoundaryHeadError, DurationModelError
from ompn_ros.detect.head import BoundaryHead, HeadDetector
from ompn_ros.detect.head_duration import HeadDurationDetector
from ompn_ros.detect.online import (
    DURATION_MODES,
    HEAD_DURATION_MODE,
    HEAD_MODE,
    DetectorConfig,
    OnlineDetector,
)

Detector = OnlineDetector | DurationDetector | HeadDetector | HeadDurationDetector
"""What :class:`~ompn_ros.segmenter.StreamingSegmenter` steps (``update``, ``close``, ``configure``,
``reset``)."""


def make_detector(config: DetectorConfig, model: DurationModel | None,
                  head: BoundaryHead | None = None) -> Detector:
    """The detector of ``config``: the threshold detector; for mode 'hsmm' the duration decoder of
    ``model`` (a :class:`DurationModelError` without one); for mode 'head' the boundary head ``head``
    (a :class:`BoundaryHeadError` without one); for 'head_hsmm' the duration decoder over the head
    (both needed)."""
    if config.mode in (HEAD_MODE, HEAD_DURATION_MODE) and head is None:
        raise BoundaryHeadError(
            f"detector mode '{config.mode}' needs a boundary head: the checkpoint's detector.json has none "
            "(ompn_train fits one on labelled bags)"
        )
    if config.mode in DURATION_MODES and model is None:
        raise DurationModelError(
            f"detector mode '{config.mode}' needs a duration model: the checkpoint's detector.json has "
            "none (ompn_train writes one when it can fit it)"
        )
    if config.mode == HEAD_MODE:
        assert head is not None
        return HeadDetector(head, config)
    if config.mode == HEAD_DURATION_MODE:
        assert head is not None and model is not None
        return HeadDurationDetector(model, head, config)
    if config.mode in DURATION_MODES:
        assert model is not None
        return DurationDetector(model, config.lag, config.high, config.force_first_step_low)
    return OnlineDetector(config)


__all__ = ["Detector", "make_detector"]
