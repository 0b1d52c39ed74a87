"""What a read used and what it did not: per-bag counts, drops with reasons, notes."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..episode import Episode

TABLES = ("missing", "duplicates", "unattached")


@dataclass
class BagReport:
    """What was read from one bag, and what was not used."""

    path: str
    episodes: int = 0
    steps: int = 0
    split: str = ""  # 'markers' | 'time_gap'
    messages: dict[str, int] = field(default_factory=dict)
    missing: dict[str, int] = field(default_factory=dict)  # steps lacking a partner, per topic
    duplicates: dict[str, int] = field(default_factory=dict)  # extra partners for one step
    unattached: dict[str, int] = field(default_factory=dict)  # messages attached to no step
    dropped_steps: int = 0
    dropped_episodes: int = 0
    final_duplicated: int = 0  # episodes whose row T duplicates the last observation
    error: str | None = None  # the corruption that ended the read (skip_tail)
    notes: list[str] = field(default_factory=list)

    def _add(self, table: dict[str, int], topic: str, n: int) -> None:
        if n:
            table[topic] = table.get(topic, 0) + int(n)


@dataclass
class ReadReport:
    """Per-bag reports of one :func:`read_episodes` call."""

    bags: list[BagReport] = field(default_factory=list)

    @property
    def episodes(self) -> int:
        return sum(b.episodes for b in self.bags)

    @property
    def steps(self) -> int:
        return sum(b.steps for b in self.bags)

    def total(self, name: str) -> dict[str, int]:
        """Sum the per-topic table ``name`` ('missing', 'duplicates', 'unattached', 'messages')."""
        out: dict[str, int] = {}
        for bag in self.bags:
            for topic, n in getattr(bag, name).items():
                out[topic] = out.get(topic, 0) + n
        return out

    @property
    def errors(self) -> list[str]:
        return [b.error for b in self.bags if b.error]

    def summary(self) -> str:
        """Human-readable multi-line summary."""
        lines = [f"{len(self.bags)} bag(s), {self.episodes} episode(s), {self.steps} step(s)"]
        for b in self.bags:
            line = f"  {b.path}: {b.episodes} episodes, {b.steps} steps ({b.split})"
            for name in TABLES:
                table = getattr(b, name)
                if table:
                    line += f"; {name} {table}"
            if b.dropped_steps:
                line += f"; dropped steps {b.dropped_steps}"
            if b.dropped_episodes:
                line += f"; dropped episodes {b.dropped_episodes}"
            if b.final_duplicated:
                line += f"; last observation duplicated as row T in {b.final_duplicated} episodes"
            lines.append(line)
            if b.error:
                lines.append(f"    error: {b.error}")
            lines.extend(f"    note: {n}" for n in b.notes)
        return "\n".join(lines)


@dataclass
class ReadResult:
    """Episodes read and the report of what was (not) used."""

    episodes: list[Episode]
    report: ReadReport
