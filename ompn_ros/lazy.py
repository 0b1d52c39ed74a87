"""A package face that imports nothing until a name is used: a sub-package's ``__init__`` lists which
module defines each public name and sets ``__getattr__ = lazy_names(__name__, globals(), NAMES)``,
so importing the package (for a command's ``--help``, say) costs nothing until a name is read."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_names(package: str, namespace: dict[str, Any], names: Mapping[str, str]) -> Callable[[str], Any]:
    """The module ``__getattr__`` of ``package``: ``name`` is imported from the module ``names[name]``
    on first use and kept in ``namespace``; any other name is an ``AttributeError``."""

    def __getattr__(name: str) -> Any:
        if name not in names:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(names[name]), name)
        namespace[name] = value
        return value

    return __getattr__
