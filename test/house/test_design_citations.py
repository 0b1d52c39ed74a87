"""Product code and shipped configs justify their behaviour by sections of docs/design.md.

Every ``docs/design.md#anchor`` they cite is a heading of docs/design.md (GitHub's anchor of the
heading), and none cites the lab log ``docs/experiments.md`` (``lab/`` may).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Final

ROOT: Final = Path(__file__).resolve().parents[2]
PRODUCT: Final = ("ompn_ros", "sim_nodes", "config", "launch")
CITED = re.compile(r"docs/design\.md#([a-z0-9-]+)")


def anchor(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def product_files() -> list[Path]:
    return [p for folder in PRODUCT for p in sorted((ROOT / folder).rglob("*"))
            if p.suffix in {".py", ".yaml", ".yml", ".xml"} and p.is_file()]


def test_cited_design_sections_exist() -> None:
    text = (ROOT / "docs" / "design.md").read_text(encoding="utf-8")
    anchors = {anchor(h) for h in re.findall(r"^##+ (.+)$", text, flags=re.MULTILINE)}
    cited = {(p.relative_to(ROOT).as_posix(), a) for p in product_files()
             for a in CITED.findall(p.read_text(encoding="utf-8", errors="replace"))}
    assert cited, "no citation of docs/design.md found: is the pattern still right?"
    missing = sorted(f"{where}: #{a}" for where, a in cited if a not in anchors)
    assert not missing, f"docs/design.md lacks the cited sections {missing}"


def test_product_does_not_cite_the_lab_log() -> None:
    citing = [p.relative_to(ROOT).as_posix() for p in product_files()
              if "experiments.md" in p.read_text(encoding="utf-8", errors="replace")]
    assert not citing, f"cite docs/design.md (or craft.md, dial.md, bags.md) instead of the lab log: {citing}"
