"""What a read used and what it did not: per-bag counts, drops with reasons, guesses, notes."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from ..episode import Episode

TABLES = ("missing", "duplicates", "unattached")
FINAL_GUESS = "row T = "
"""How every ``guessed`` entry about an episode's final observation begins (:func:`final_row_guessed`)."""
MAX_BAG_LINES = 8  # summary(): bags listed one per line before "... and N more"
MAX_NOTES = 4  # summary(): notes shown per bag


@dataclass
class BagReport:
    """What was read from one bag, and what was not used.

    ``dropped`` maps a reason to the number of episodes dropped for it (``dropped_episodes`` is
    their sum); ``obs_dropped`` maps a reason of the observation rule (``ReaderSpec.assemble``:
    ``missing``, ``stale``, ``malformed``, ``wrong_size``, ``wrong_type``) to the steps it dropped, and
    ``obs_rejected`` counts the partner messages it rejected (``'<topic>: <reason>'``); ``guessed``
    lists what the reader inferred rather than read (a topic found by its suffix, a final observation
    duplicated, ordinals derived from ids); ``adjusted`` maps a
    ``final_observation`` / label handling to the episodes (by index in this bag) it applied to.
    """

    path: str
    episodes: int = 0
    steps: int = 0
    split: str = ""  # 'markers' | 'time_gap' | 'topic' | 'idle' | 'bag'
    idle_trimmed: int = 0  # split: idle: still observations that belong to no episode
    idle_rule: str = ""  # split: idle: the speed threshold used (derived with idle_speed: auto) and on what
    messages: dict[str, int] = field(default_factory=dict)
    missing: dict[str, int] = field(default_factory=dict)  # steps lacking a partner, per topic
    duplicates: dict[str, int] = field(default_factory=dict)  # extra partners for one step
    unattached: dict[str, int] = field(default_factory=dict)  # messages attached to no step
    dropped_steps: int = 0
    obs_dropped: dict[str, int] = field(default_factory=dict)  # reason -> steps (ReaderSpec.assemble)
    obs_rejected: dict[str, int] = field(default_factory=dict)  # '<topic>: <reason>' -> messages
    dropped_episodes: int = 0
    dropped: dict[str, int] = field(default_factory=dict)  # reason -> episodes
    final_duplicated: int = 0  # episodes whose row T duplicates the last observation
    adjusted: dict[str, list[int]] = field(default_factory=dict)  # handling -> episode indices
    guessed: list[str] = field(default_factory=list)
    error: str | None = None  # the corruption that ended the read (skip_tail)
    notes: list[str] = field(default_factory=list)

    def _add(self, table: dict[str, int], topic: str, n: int) -> None:
        if n:
            table[topic] = table.get(topic, 0) + int(n)

    def drop_episode(self, reason: str, note: str | None = None) -> None:
        """Count one dropped episode under ``reason`` (and keep ``note``, its details)."""
        self.dropped_episodes += 1
        self._add(self.dropped, reason, 1)
        if note:
            self.notes.append(note)

    def line(self) -> str:
        """One line: counts, tables and drops of this bag."""
        text = f"{self.path}: {self.episodes} episodes, {self.steps} steps ({self.split or 'nothing read'})"
        for name in TABLES:
            table = getattr(self, name)
            if table:
                text += f"; {name} {table}"
        if self.dropped_steps:
            text += f"; dropped steps {self.dropped_steps}"
        if self.obs_dropped:
            text += f"; observation rule dropped steps {self.obs_dropped}"
        if self.dropped_episodes:
            text += f"; dropped episodes {self.dropped_episodes} {self.dropped or ''}".rstrip()
        if self.final_duplicated:
            text += f"; last observation duplicated as row T in {self.final_duplicated} episodes"
        for handling, episodes in self.adjusted.items():
            text += f"; {handling} in {len(episodes)} episodes"
        if self.idle_rule:
            text += f"; {self.idle_rule}"
        return text


def final_row_guessed(summary: str) -> bool:
    """Whether a :meth:`ReadReport.summary` (the text a cache keeps) says the reader guessed row T of
    some episode (``final_observation``: duplicate, blank or extrapolate).  O(len(summary))."""
    return any(line.startswith("guessed: ") and FINAL_GUESS in line for line in summary.splitlines())


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
        """Sum the per-topic table ``name`` ('missing', 'duplicates', 'unattached', 'messages',
        'dropped', 'obs_dropped', 'obs_rejected')."""
        out: dict[str, int] = {}
        for bag in self.bags:
            for topic, n in getattr(bag, name).items():
                out[topic] = out.get(topic, 0) + n
        return out

    @property
    def errors(self) -> list[str]:
        return [b.error for b in self.bags if b.error]

    def summary(self) -> str:
        """What was read, dropped (with reasons), duplicated or guessed; fits one screen."""
        lines = [f"read {len(self.bags)} bag(s): {self.episodes} episode(s), {self.steps} step(s)"]
        dropped = self.total("dropped")
        steps = sum(b.dropped_steps for b in self.bags)
        if dropped or steps:
            reasons = ", ".join(f"{n} {reason}" for reason, n in dropped.items())
            lines.append(f"dropped: {sum(dropped.values())} episode(s) ({reasons or '-'}), {steps} step(s)")
        obs_dropped = self.total("obs_dropped")
        if obs_dropped:
            reasons = ", ".join(f"{n} {reason}" for reason, n in obs_dropped.items())
            lines.append(f"observation rule dropped {sum(obs_dropped.values())} step(s) ({reasons})")
        dup = self.total("duplicates")
        final = sum(b.final_duplicated for b in self.bags)
        if dup or final:
            lines.append(f"duplicated: partners {dup or '-'}; last observation as row T in {final} "
                         "episode(s)")
        guessed = sorted({g for b in self.bags for g in b.guessed})
        if guessed:
            lines.append("guessed: " + "; ".join(guessed))
        for b in self.bags[:MAX_BAG_LINES]:
            lines.append("  " + b.line())
            if b.error:
                lines.append(f"    error: {b.error}")
            lines.extend(f"    note: {n}" for n in b.notes[:MAX_NOTES])
            if len(b.notes) > MAX_NOTES:
                lines.append(f"    ... and {len(b.notes) - MAX_NOTES} more note(s) (ReadReport.to_dict())")
        if len(self.bags) > MAX_BAG_LINES:
            lines.append(f"  ... and {len(self.bags) - MAX_BAG_LINES} more bag(s)")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready mapping: totals plus every bag's full report."""
        return {
            "episodes": self.episodes,
            "steps": self.steps,
            "dropped": self.total("dropped"),
            "obs_dropped": self.total("obs_dropped"),
            "errors": self.errors,
            "bags": [asdict(b) for b in self.bags],
        }


@dataclass
class ReadResult:
    """Episodes read and the report of what was (not) used."""

    episodes: list[Episode]
    report: ReadReport
