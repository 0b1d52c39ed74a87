"""Message types beyond ROS 2 Jazzy's: registered from a bag's own definitions, a folder of ``.msg``
files or an installed interface package, into the package's one typestore (:func:`.cdr.typestore`).

* A bag: rosbag2 stores each topic's definition (sqlite3 ``message_definitions`` table, mcap schemas)
  as ``ros2msg`` text (the type's own fields, then ``MSG: pkg/msg/Dep`` sections separated by ``=``
  lines) or ``ros2idl``; :func:`register_definition` registers the types it holds.
* A folder (:func:`register_folder`): ``<pkg>/msg/*.msg`` below it (or the folder is ``<pkg>`` itself).
* A package (:func:`register_package`): its ``share/<pkg>/msg`` in the ament prefixes.

A type already in the typestore is kept (the Jazzy definitions win over a bag's); a definition that
cannot be parsed raises :class:`TypeDefinitionError` naming the type.  Types are registered
process-wide; registering the same definition again is a no-op.
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from ompn_ros.errors import OMPNError

from . import fieldpath
from .cdr import typestore

_SECTION = re.compile(r"^=+\s*$", re.MULTILINE)
_MSG_HEADER = re.compile(r"^\s*MSG:\s*(\S+)\s*$", re.MULTILINE)
_IDL_HEADER = re.compile(r"^\s*IDL:\s*\S+\s*$", re.MULTILINE)


class TypeDefinitionError(OMPNError, ValueError):
    """A message definition that cannot be registered, or a type that no source defines."""


def full_name(name: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type`` (``pkg/msg/Type`` unchanged)."""
    parts = name.strip("/").split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else "/".join(parts)


def known(typename: str) -> bool:
    """Whether ``typename`` is in the typestore (Jazzy's or registered)."""
    return typename in typestore().fielddefs


def register_definition(typename: str, fmt: str, text: str) -> list[str]:
    """Register the types of one embedded definition (``fmt``: 'msg' or 'idl'); the names added.  A
    type registered before (another bag's, a folder's) must have the same fields, else
    :class:`TypeDefinitionError`: one name, two definitions, never one read as the other."""
    if builtin(typename) or not text.strip() or _TEXTS.get(typename) == text:
        return []
    from rosbags.typesys import get_types_from_idl, get_types_from_msg

    try:
        if fmt == "idl":  # rosbag2's ros2idl: IDL files after 'IDL: pkg/msg/Type', '=' lines between
            types = {}
            for section in _SECTION.split(text):
                # rosidl's files start with #include lines, which rosbags' IDL parser refuses: dropped
                lines = _IDL_HEADER.sub("", section).splitlines()
                body = "\n".join(x for x in lines if not x.lstrip().startswith("#")).strip()
                if body:
                    types.update(get_types_from_idl(body + "\n"))
        else:
            types = {}
            sections = _SECTION.split(text)
            types.update(get_types_from_msg(sections[0], typename))
            for section in sections[1:]:
                header = _MSG_HEADER.search(section)
                if header is not None:
                    body = section[header.end() :]
                    types.update(get_types_from_msg(body, full_name(header.group(1))))
    except Exception as err:  # rosbags' parsers raise several types on a bad definition
        raise TypeDefinitionError(f"the definition of {typename} cannot be parsed: {err}") from err
    added = _register(types)
    _TEXTS[typename] = text  # the same text again (the next bag of a lab) is not parsed again
    return added


_REGISTERED: set[str] = set()  # the names this process added to the Jazzy typestore
_TEXTS: dict[str, str] = {}  # type -> the embedded definition registered for it


def builtin(typename: str) -> bool:
    """Whether ``typename`` is one of ROS 2 Jazzy's types (known without registering)."""
    return known(typename) and typename not in _REGISTERED


def _register(types: dict[str, Any]) -> list[str]:
    """Register ``types`` but Jazzy's own; a name registered before with other fields is refused."""
    from rosbags.typesys import TypesysError

    mine = {name: tree for name, tree in types.items() if not builtin(name)}
    new = sorted(name for name in mine if not known(name))
    if mine:
        try:
            typestore().register(mine)  # rosbags compares the fields of names it holds already
        except TypesysError as err:
            raise TypeDefinitionError(f"{err} (read before from another bag or folder): read bags of the two "
                                      "definitions in separate runs") from None
        _REGISTERED.update(new)
    return new


def register_folder(folder: str | Path) -> list[str]:
    """Register every ``.msg`` file below ``folder`` as ``<pkg>/msg/<Name>``, ``<pkg>`` being the folder
    that holds its ``msg`` folder (or ``folder`` itself for ``.msg`` files directly in it)."""
    from rosbags.typesys import get_types_from_msg

    root = Path(folder)
    files = _msg_files(root)
    if not files:
        raise TypeDefinitionError(f"types: no .msg file below '{root}' (expected <pkg>/msg/<Name>.msg)")
    types: dict[str, Any] = {}
    for file in files:
        pkg = file.parent.parent.name if file.parent.name == "msg" else file.parent.name
        name = f"{pkg}/msg/{file.stem}"
        try:
            types.update(get_types_from_msg(file.read_text(encoding="utf-8"), name))
        except Exception as err:  # rosbags' parser raises several types on a bad definition
            raise TypeDefinitionError(
                f"types: '{file}' is not a valid .msg definition of {name}: {err}"
            ) from err
    return _register(types)


def _msg_files(root: Path) -> list[Path]:
    return sorted(root.rglob("*.msg"))


def source_files(source: str) -> list[Path]:
    """The ``.msg`` files the ``types:`` source names, as :func:`register_sources` registers them (a
    folder's, or an installed package's ``share/<pkg>/msg``); none for a source that names neither
    (refused in one line when one of its types is needed).  What the episode cache's key covers."""
    root = Path(source) if Path(source).is_dir() else package_share(source)
    return _msg_files(root) if root is not None else []


def package_share(package: str) -> Path | None:
    """``share/<package>`` of an installed ROS package (ament prefixes, then this Python's prefix)."""
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    for prefix in [*prefixes, sys.prefix]:
        share = Path(prefix) / "share" / package
        if (share / "msg").is_dir():
            return share
    return None


def register_package(package: str) -> list[str]:
    """Register the ``.msg`` files of an installed interface package."""
    share = package_share(package)
    if share is None:
        raise TypeDefinitionError(
            f"types: '{package}' is neither a folder nor an installed interface "
            "package (no share/<pkg>/msg in AMENT_PREFIX_PATH)"
        )
    return register_folder(share)


def register_sources(sources: Iterable[str]) -> list[str]:
    """Register each source: a folder of ``.msg`` files or an installed package name."""
    added: list[str] = []
    for source in sources:
        added += register_folder(source) if Path(source).is_dir() else register_package(source)
    return added


def ensure(typename: str, sources: Iterable[str] = ()) -> None:
    """Make ``typename`` known: registered already, or by ``sources``, or by its installed package;
    :class:`TypeDefinitionError` naming the way out otherwise."""
    if known(typename):
        return
    register_sources(sources)
    package = typename.split("/", 1)[0]
    if not known(typename) and package_share(package) is not None:
        register_package(package)
    if not known(typename):
        raise TypeDefinitionError(
            f"type {typename} is not in the bag's definitions nor the typestore: name its .msg folder "
            f"with `types: DIR` in the spec, or install its package ({package})"
        )


def forget(names: Iterable[str]) -> None:
    """Drop types this process registered (a process that reads bags whose definitions of one name
    differ, tests); Jazzy's own types stay."""
    store = typestore()
    for name in set(names) & _REGISTERED:
        _REGISTERED.discard(name)
        _TEXTS.pop(name, None)
        for table in (store.fielddefs, store.types, store.cache, fieldpath.FIELD_CACHE):
            table.pop(name, None)
