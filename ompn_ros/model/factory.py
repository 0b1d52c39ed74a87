"""Former home of the builders; kept so existing imports keep working.

New code imports :mod:`ompn_ros.model.build` (config -> model) and :mod:`ompn_ros.model.load`
(path -> stepper).
"""

from __future__ import annotations

from ompn_ros.model.build import PolicyModule, build_policy
from ompn_ros.model.load import Stepper, build_stepper, stepper_from_checkpoint

__all__ = ["PolicyModule", "Stepper", "build_policy", "build_stepper", "stepper_from_checkpoint"]
