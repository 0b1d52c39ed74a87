"""The online detector as node parameters: which value wins, and whether a set of values can run.

``ompn_node`` declares the detector's parameters (``NODE_PARAMETERS`` of :mod:`ompn_ros.detect.settings`)
and fills them at configure from the checkpoint's ``detector.json``.  Precedence: a parameter given
explicitly (``-p``, a params file, the launch file's YAML, or set later) beats ``detector.json``, which
beats the built-in defaults (docs/parameters.md).  :class:`DetectorParameters` keeps which names were
given and the checkpoint's settings, and checks a change through
:func:`ompn_ros.detect.factory.make_detector`, the builder the segmenter runs, so a refusal and a
configure failure say the same thing.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any

from ompn_ros.detect.errors import BoundaryHeadError, DetectorConfigError, DurationModelError
from ompn_ros.detect.factory import make_detector
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.detect.settings import (
    DETECTOR_PARAMETERS,
    NODE_PARAMETERS,
    DetectorSettings,
    detector_config,
    node_parameters,
    resolve_detector,
)

__all__ = ["DetectorParameters"]


class DetectorParameters:
    """The detector parameters of one node: precedence and validation.

    Args:
        given: the parameter names given explicitly at start-up (command line, params file); each name
            set later is added by :meth:`changed`.
    """

    def __init__(self, given: Iterable[str]) -> None:
        names = set(given)
        self.explicit = {name for name in NODE_PARAMETERS if name in names}
        self.settings: DetectorSettings | None = None  # the checkpoint's, while one is loaded
        self._loading = False

    @staticmethod
    def config(values: Mapping[str, Any]) -> DetectorConfig:
        """The detector of the parameter ``values``; :class:`DetectorConfigError` when they do not fit
        each other (``detector_hysteresis`` above ``detector_high``)."""
        return detector_config(values)

    def refusal(self, values: Mapping[str, Any]) -> str | None:
        """Why the parameter ``values`` cannot run (one line), else ``None``.  With a checkpoint loaded,
        the detector is built as the segmenter would build it, with the checkpoint's duration model and
        boundary head (a mode without them, or a lag beyond the head's, is refused)."""
        try:
            config = detector_config(values)
            if self.settings is not None and not self._loading:
                make_detector(config, self.settings.duration_model, self.settings.head)
        except (DetectorConfigError, DurationModelError, BoundaryHeadError) as exc:
            return str(exc)
        return None

    def changed(self, names: Iterable[str]) -> bool:
        """Note parameters that were set (explicit unless :meth:`load` set them); whether the detector
        changed."""
        names = set(names)
        if not self._loading:
            self.explicit |= names & set(NODE_PARAMETERS)
        return bool(names & set(DETECTOR_PARAMETERS))

    def load(self, checkpoint: str,
             apply: Callable[[dict[str, Any]], object]) -> tuple[DetectorSettings, str]:
        """Read ``checkpoint``'s ``detector.json`` and ``apply`` its values to the parameters nobody gave
        explicitly (the ROS parameters then show what runs); the settings (their duration model and
        boundary head) and the line to log: which settings run, where they came from, what overrides
        them.  Raises :class:`~ompn_ros.detect.errors.DetectorSettingsError` on an invalid file."""
        settings, line = resolve_detector(checkpoint)
        stored = node_parameters(settings)
        self._loading = True
        try:
            apply({name: stored[name] for name in NODE_PARAMETERS if name not in self.explicit})
        finally:
            self._loading = False
        self.settings = settings
        explicit = sorted(self.explicit)
        return settings, f"{line}; overridden by parameters: {explicit}" if explicit else line

    def unload(self) -> None:
        """The checkpoint is gone (cleanup, a failed configure): changes are checked on their own."""
        self.settings = None
