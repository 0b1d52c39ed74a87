"""Errors of the services behind the ``ompn_*`` commands: training setup, replay and batch runs,
annotated copies, collection and closed-loop evaluation.

Every class derives from :class:`ompn_ros.errors.OMPNError`; the message names the option, file or episode
at fault.
"""

from __future__ import annotations

from ompn_ros.data.errors import BagError
from ompn_ros.errors import OMPNError


class ReplayError(OMPNError, ValueError):
    """A replay (``ompn_segment``, one bag or many) cannot run or be scored: names the option,
    checkpoint or episode at fault."""


class TrainSetupError(OMPNError, ValueError):
    """A bad config file, override, data section or output directory (names the thing at fault)."""


class ClosedLoopError(OMPNError, ValueError):
    """Bad arguments to a closed-loop evaluation (unknown domain or task, wrong counts, ...)."""


class CollectError(OMPNError, RuntimeError):
    """The collection cannot start or continue (existing output, mismatched resume, ...)."""


class RosEvalError(OMPNError, RuntimeError):
    """A child process failed or the evaluation timed out; the message carries the children's stderr."""


class AnnotateError(BagError):
    """The input bag, the output path or the replay outputs cannot make an annotated bag."""
