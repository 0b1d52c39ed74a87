"""Errors of the detectors: offline and online detector parameters, ``detector.json``, the duration
model, the boundary head, tuning and calibration input.

Every class derives from :class:`ompn_ros.errors.OMPNError` (and ``ValueError``); the message names the
parameter, key or argument at fault.
"""

from __future__ import annotations

from ompn_ros.errors import OMPNError


class DetectorError(OMPNError, ValueError):
    """Invalid input to an offline detector (names the argument at fault)."""


class DetectorConfigError(OMPNError, ValueError):
    """A detector parameter is out of range; the message names the parameter."""


class DetectorSettingsError(OMPNError, ValueError):
    """An invalid ``detector.json`` or settings value; the message names the file and the key."""


class DurationModelError(OMPNError, ValueError):
    """An invalid duration model, or episodes a model cannot be fitted on; the message says which."""


class BoundaryHeadError(OMPNError, ValueError):
    """An invalid boundary head, its file, or input it cannot read; the message says which."""


class TuneError(OMPNError, ValueError):
    """Bad input to detector scoring or tuning (names the argument at fault)."""


class CalibrationError(OMPNError, ValueError):
    """Input that cannot be calibrated on (names the argument at fault)."""
