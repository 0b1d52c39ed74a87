"""ARCHITECTURE.md matches the tree: every room of the package is on its map, every path it names
exists (from the repository root or inside ``ompn_ros/``), and it fits a screen."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOC = (ROOT / "ARCHITECTURE.md").read_text()
SCREEN_LINES = 60


def _rooms() -> list[str]:
    """The top-level modules and sub-packages of ``ompn_ros`` (what the floor map must place)."""
    package = ROOT / "ompn_ros"
    names = [p.stem for p in package.glob("*.py") if p.name != "__init__.py"]
    names += [p.name for p in package.iterdir() if (p / "__init__.py").is_file()]
    return sorted(names)


def test_every_room_of_the_package_is_on_the_map():
    floors = DOC.split("## Floors", 1)[1].split("```")[1]
    missing = [name for name in _rooms() if not re.search(rf"\b{re.escape(name)}\b", floors)]
    assert not missing, f"ARCHITECTURE.md's floor map does not place: {missing}"


def test_named_paths_exist():
    named = set(re.findall(r"`([\w./-]+/[\w./-]*|[\w/-]+\.(?:py|md))`", DOC))
    assert named, "the check found no path in ARCHITECTURE.md"
    missing = sorted(p for p in named if not any((base / p).exists() for base in (ROOT, ROOT / "ompn_ros")))
    assert not missing, f"ARCHITECTURE.md names paths that do not exist: {missing}"


def test_it_fits_a_screen():
    assert len(DOC.splitlines()) <= SCREEN_LINES
