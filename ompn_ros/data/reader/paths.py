"""Where the bags are: files, bag directories, directories of bags and globs; their topic types."""

from __future__ import annotations

import glob as globmod
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ompn_ros import layout
from ompn_ros.layout import resolve_topic

from ..errors import BagNotFoundError
from .reindex import needs_reindex, split_files
from .spec import ReaderSpec

STORAGE_SUFFIXES = (".mcap", ".db3")


@dataclass(frozen=True)
class BagListing:
    """What a listing found: ``bags`` in order, and ``refused``: ``(path, reason)`` of every entry
    inside a listed folder that could not be looked at (unreadable, vanished), each on its own."""

    bags: list[Path]
    refused: list[tuple[Path, str]] = field(default_factory=list)


def list_bag_paths(paths: str | Path | Sequence[str | Path]) -> BagListing:
    """Expand files, bag directories, directories of bags and globs into the bags they hold, in order.

    Symbolic links are followed, each real directory once (a link back up the tree, or a second link
    to a folder already listed, adds nothing), and a bag reached by several paths is listed once, by
    its first path.  An entry below a listed folder that cannot be looked at is refused on its own
    (:attr:`BagListing.refused`); a given path or glob that names no bag raises
    :class:`~ompn_ros.data.errors.BagNotFoundError`.  O(entries of the listed folders).
    """
    items = [paths] if isinstance(paths, (str, Path)) else list(paths)
    walk = _Walk()
    for item in items:
        text = str(item)
        if any(ch in text for ch in "*?[") and not Path(text).exists():
            matches = _glob(text)
            if not matches:
                raise BagNotFoundError("glob matched nothing", path=text)
            for match in matches:
                walk.top(Path(match), text)
        elif not walk.top(Path(text), text):
            raise BagNotFoundError("no rosbag2 bag (metadata.yaml, .mcap or .db3) found", path=text)
    return BagListing(_whole_split_bags(walk.unique()), walk.refused)


def _glob(pattern: str) -> list[str]:
    """The sorted matches of ``pattern``; ``**`` descends into real folders only (a link loop under it
    would otherwise multiply the matches without end), the other parts follow links."""
    if "**" not in pattern:
        return sorted(globmod.glob(pattern))
    parts = Path(pattern).parts
    fixed = next(i for i, part in enumerate(parts) if any(ch in part for ch in "*?["))
    base = Path(*parts[:fixed]) if fixed else Path(".")
    return sorted(str(p) if fixed else str(p.relative_to(".")) for p in base.glob(str(Path(*parts[fixed:]))))


def resolve_bag_paths(paths: str | Path | Sequence[str | Path]) -> list[Path]:
    """:func:`list_bag_paths`, where any entry that cannot be looked at refuses the whole listing."""
    listing = list_bag_paths(paths)
    if listing.refused:
        path, reason = listing.refused[0]
        raise BagNotFoundError(reason, path=path)
    return listing.bags


def _whole_split_bags(bags: list[Path]) -> list[Path]:
    """Storage files given one by one that are the split files of one bag directory become that bag
    (read as one, in split order: :mod:`.reindex`); a part of the splits is refused in one line."""
    out: list[Path] = []
    splits: dict[Path, list[Path]] = {}  # one directory listing per parent
    for bag in bags:
        if bag.is_file() and bag.parent not in splits:
            splits[bag.parent] = split_files(bag.parent)
        series = splits[bag.parent] if bag.is_file() else []
        if len(series) < 2 or bag not in series:
            out.append(bag)
            continue
        given = [f for f in series if f in bags]
        if len(given) != len(series):
            missing = [f.name for f in series if f not in given]
            raise BagNotFoundError(f"is one of the {len(series)} split files of bag '{bag.parent}' and "
                                   f"{missing} are not given; pass the bag directory to read it as one bag",
                                   path=bag)
        out.append(bag.parent)
    return list(dict.fromkeys(out))


class _Walk:
    """One listing: the bags found, the real directories entered, the entries refused."""

    def __init__(self) -> None:
        self.found: list[Path] = []
        self.entered: set[tuple[int, int]] = set()
        self.refused: list[tuple[Path, str]] = []

    def top(self, path: Path, given: str) -> bool:
        """List ``path`` as given by the user (missing or not a bag: raises); True when it held bags."""
        if not path.exists():
            raise BagNotFoundError("no such file or directory", path=path)
        before = len(self.found) + len(self.refused)
        if path.is_file():
            if path.suffix in STORAGE_SUFFIXES:
                self.found.append(path)
            elif path.name == "metadata.yaml":
                self.found.append(path.parent)
            else:
                raise BagNotFoundError(f"not a bag storage file (expected {STORAGE_SUFFIXES})", path=path)
        else:
            self._folder(path)
        return len(self.found) + len(self.refused) > before

    def _folder(self, path: Path) -> None:
        """A bag directory, or a folder whose bags (and folders) are listed, each real directory once."""
        info = path.stat()
        if (info.st_dev, info.st_ino) in self.entered:
            return  # a symbolic link loop, or a folder reached by a second link
        self.entered.add((info.st_dev, info.st_ino))
        if (path / "metadata.yaml").is_file() or needs_reindex(path):
            self.found.append(path)  # a bag; a split bag without metadata.yaml is reindexed while read
            return
        for child in sorted(path.iterdir()):
            if child.name.startswith("."):
                continue  # temp parts of ompn_collect, hidden directories
            try:
                if child.is_dir():
                    self._folder(child)
                elif child.suffix in STORAGE_SUFFIXES:
                    self.found.append(child)  # a dangling link too: refused when read, on its own
            except OSError as exc:
                self.refused.append((child, f"cannot be listed: {exc.strerror or exc}"))

    def unique(self) -> list[Path]:
        """The bags found, each real path once (its first path kept)."""
        seen: dict[str, Path] = {}
        for bag in self.found:
            seen.setdefault(os.path.realpath(bag), bag)
        return list(seen.values())


def storage_files(bag: Path) -> list[Path]:
    """The storage files of a bag (the file itself, or the ``.mcap``/``.db3`` files of the dir)."""
    if bag.is_file():
        return [bag]
    return sorted(p for p in bag.iterdir() if p.suffix in STORAGE_SUFFIXES)


_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def metadata_topic_types(bag: Path) -> dict[str, str] | None:
    """Topic -> type from the bag's metadata without reading messages (None if unreadable)."""
    meta = bag / "metadata.yaml" if bag.is_dir() else None
    if meta is None or not meta.is_file():
        return None
    try:
        # libyaml's loader where PyYAML has it: parsed once per bag, the pure Python loader was a large
        # share of a short bag's segmentation (docs/scale.md)
        info = yaml.load(meta.read_text(encoding="utf-8"), Loader=_SAFE_LOADER)["rosbag2_bagfile_information"]
        return {t["topic_metadata"]["name"]: t["topic_metadata"]["type"]
                for t in info["topics_with_message_count"]}
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return None


def wanted_topics(spec: ReaderSpec, types: dict[str, str]) -> set[str]:
    """Bag topics the spec may use: resolved names plus unique ``/<name>`` suffix matches."""
    wanted = set()
    for name in spec_topic_names(spec):
        wanted.add(resolve_topic(name, spec.namespace))
        if not name.startswith("/"):
            wanted.update(t for t in types if t.endswith("/" + name))
    return wanted


def spec_topic_names(spec: ReaderSpec) -> list[str]:
    """Every topic name the spec refers to (as written in the spec)."""
    observed = list(spec.assemble.topics) if spec.assemble is not None else [spec.observation.topic]
    names = [*observed, spec.action.topic, spec.subtask, spec.sketch, spec.episode, spec.joint_states,
             spec.split_topic]
    if spec.episode == layout.EPISODE:  # the typed markers, read instead when the bag has them
        names.append(layout.EPISODE_MARKER)
    return [n for n in names if n is not None]
