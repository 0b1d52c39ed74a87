"""Where the bags are: files, bag directories, directories of bags and globs; their topic types."""

from __future__ import annotations

import glob as globmod
from collections.abc import Sequence
from pathlib import Path

import yaml

from ompn_ros import layout
from ompn_ros.layout import resolve_topic

from ..errors import BagNotFoundError
from .reindex import needs_reindex, split_files
from .spec import ReaderSpec

STORAGE_SUFFIXES = (".mcap", ".db3")


def resolve_bag_paths(paths: str | Path | Sequence[str | Path]) -> list[Path]:
    """Expand files, bag directories, directories of bags and globs into a sorted list of bags."""
    items = [paths] if isinstance(paths, (str, Path)) else list(paths)
    out: list[Path] = []
    for item in items:
        text = str(item)
        if any(ch in text for ch in "*?[") and not Path(text).exists():
            matches = sorted(globmod.glob(text, recursive=True))
            if not matches:
                raise BagNotFoundError("glob matched nothing", path=text)
            for match in matches:
                out.extend(_expand(Path(match)))
        else:
            found = _expand(Path(text))
            if not found:
                raise BagNotFoundError("no rosbag2 bag (metadata.yaml, .mcap or .db3) found", path=text)
            out.extend(found)
    return _whole_split_bags(list(dict.fromkeys(out)))


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


def _expand(path: Path) -> list[Path]:
    if not path.exists():
        raise BagNotFoundError("no such file or directory", path=path)
    if path.is_file():
        if path.suffix in STORAGE_SUFFIXES:
            return [path]
        if path.name == "metadata.yaml":
            return [path.parent]
        raise BagNotFoundError(f"not a bag storage file (expected {STORAGE_SUFFIXES})", path=path)
    if (path / "metadata.yaml").is_file() or needs_reindex(path):
        return [path]  # a bag; a split bag without metadata.yaml is reindexed while read
    found: list[Path] = []
    for child in sorted(path.iterdir()):
        if child.name.startswith("."):
            continue  # temp parts of ompn_collect, hidden directories
        if child.is_dir():
            found.extend(_expand(child))
        elif child.suffix in STORAGE_SUFFIXES:
            found.append(child)
    return found


def storage_files(bag: Path) -> list[Path]:
    """The storage files of a bag (the file itself, or the ``.mcap``/``.db3`` files of the dir)."""
    if bag.is_file():
        return [bag]
    return sorted(p for p in bag.iterdir() if p.suffix in STORAGE_SUFFIXES)


def metadata_topic_types(bag: Path) -> dict[str, str] | None:
    """Topic -> type from the bag's metadata without reading messages (None if unreadable)."""
    meta = bag / "metadata.yaml" if bag.is_dir() else None
    if meta is None or not meta.is_file():
        return None
    try:
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
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
