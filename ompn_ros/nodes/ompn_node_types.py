"""The message types ``ompn_node`` subscribes to: any type installed in the environment, by name.

``observation_spec`` names each topic's type (``pkg/msg/Type``).  The node subscribes with the rclpy
class of that type (``import pkg.msg``, as ``ros2 topic echo`` finds it) and reads its fields from the
raw CDR through the type's definition, which it registers from the package's ``share/<pkg>/msg``
folder (:mod:`ompn_ros.data.messages.types`), so the fields a spec names read live as they read from a
bag (:mod:`ompn_ros.data.messages.fieldpath`).  A type that is not installed is one line naming the
package to install; configure then fails.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

from ompn_ros.data.messages.types import TypeDefinitionError, ensure, known, register_folder
from ompn_ros.data.obs import ObservationSpecError


def message_class(typename: str, fast: dict[str, Any]) -> Any:
    """The rclpy class of ``typename`` (``pkg/msg/Type``): one of ``fast`` (the hand-parsed types), else
    imported from the installed package, its definition registered for field paths.

    Raises:
        ObservationSpecError: the type is not installed, or its definition cannot be found (one line).
    """
    if typename in fast:
        return fast[typename]
    package, _, name = typename.split("/")
    try:
        cls = getattr(importlib.import_module(f"{package}.msg"), name)
    except (ImportError, AttributeError):
        raise ObservationSpecError(
            f"message type {typename} is not installed: install its package '{package}' (e.g. apt install "
            f"ros-jazzy-{package.replace('_', '-')}, or build it in your workspace) and source its setup "
            "before starting ompn_node"
        ) from None
    if not known(typename):
        _register_definition(typename, cls)
    return cls


def _register_definition(typename: str, cls: Any) -> None:
    """The definition of an installed type: its ``share/<pkg>/msg`` in the ament prefixes, or beside the
    Python package it was imported from (``<prefix>/lib/pythonX.Y/site-packages/<pkg>``)."""
    package = typename.split("/", 1)[0]
    module = importlib.import_module(cls.__module__)
    for parent in Path(module.__file__ or ".").resolve().parents:
        share = parent / "share" / package
        if (share / "msg").is_dir():
            register_folder(share)
            break
    try:
        ensure(typename)
    except TypeDefinitionError as err:
        raise ObservationSpecError(
            f"{err} (the package is installed without its share/{package}/msg "
            "folder: source its setup so that AMENT_PREFIX_PATH names it)"
        ) from None
