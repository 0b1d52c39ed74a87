"""What a read used and what it did not: per-bag counts, drops with reasons, guesses, notes."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from ..episode import Episode

TABLES = ("missing", "duplicates", "unattached")
FINAL_GUESS = "row T = "
"""How every ``guessed`` entry about an episode's final observation begins (the summary's words; the
count is :attr:`BagFacts.final_guessed`)."""
DROPPED_LAST = "last step dropped (no final observation)"
DUPLICATED_LAST = "last observation duplicated as row T"
BLANK_LAST = "row T left blank (zeros; no final observation)"
EXTRAPOLATED_LAST = "row T extrapolated from the last two observations (no final observation)"
GUESSED_LAST = (DUPLICATED_LAST, BLANK_LAST, EXTRAPOLATED_LAST)  # ``adjusted`` keys of a guessed row T
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
    idle_trimmed: int = 0  # split: idle: idle observations that belong to no episode
    idle_rule: str = ""  # split: idle: the speed threshold used (derived with idle_speed: auto) and on what
    idle_speed: float | None = None  # split: idle: that threshold, at full precision
    idle_on: str = ""  # split: idle: what speed it is a threshold of (SpeedElements.describe())
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

    def count(self, table: dict[str, int], topic: str, n: int) -> None:
        """Add ``n`` to ``table[topic]`` (one of this report's tables: missing, duplicates, ...)."""
        if n:
            table[topic] = table.get(topic, 0) + int(n)

    def drop_episode(self, reason: str, note: str | None = None) -> None:
        """Count one dropped episode under ``reason`` (and keep ``note``, its details)."""
        self.dropped_episodes += 1
        self.count(self.dropped, reason, 1)
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


@dataclass(frozen=True)
class BagFacts:
    """The facts of one bag's read that are used after the read (training, its records), as data: the
    cache keeps them beside the summary text (:meth:`ReadReport.facts`), so nothing parses that text.

    ``final_guessed``: episodes whose row T the reader guessed (``final_observation`` duplicate, blank
    or extrapolate); ``idle_speed``: the idle rule's threshold (``None``: the bag was not read with the
    idle rule) and ``idle_on`` what speed it is a threshold of
    (:meth:`ompn_ros.data.cuts.SpeedElements.describe`).
    """

    path: str
    episodes: int = 0
    steps: int = 0
    final_guessed: int = 0
    idle_speed: float | None = None
    idle_on: str = ""

    @classmethod
    def from_dict(cls, doc: Any) -> BagFacts:
        """The facts of :func:`dataclasses.asdict`; ``ValueError`` naming the field that does not hold."""
        if not isinstance(doc, Mapping) or set(doc) != set(cls.__dataclass_fields__):
            raise ValueError(f"read facts {doc!r}: expected the fields {sorted(cls.__dataclass_fields__)}")
        counts = {name: doc[name] for name in ("episodes", "steps", "final_guessed")}
        speed = doc["idle_speed"]
        bad = [name for name, n in counts.items() if isinstance(n, bool) or not isinstance(n, int) or n < 0]
        if speed is not None and (isinstance(speed, bool) or not isinstance(speed, int | float)
                                  or not speed >= 0):
            bad.append("idle_speed")
        bad += [name for name in ("path", "idle_on") if not isinstance(doc[name], str)]
        if bad:
            raise ValueError(f"read facts of {doc['path']!r}: {', '.join(bad)} do not hold (counts are "
                             "integers >= 0, idle_speed a number >= 0 or null, path and idle_on text)")
        return cls(doc["path"], **counts, idle_speed=None if speed is None else float(speed),
                   idle_on=doc["idle_on"])


def final_row_guessed(facts: Sequence[BagFacts]) -> bool:
    """Whether the reader guessed row T of some episode (``final_observation``: duplicate, blank or
    extrapolate), from the read's facts (:meth:`ReadReport.facts`, as the cache keeps them)."""
    return any(bag.final_guessed for bag in facts)


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

    def facts(self) -> tuple[BagFacts, ...]:
        """The facts of every bag (:class:`BagFacts`): what is used after the read, as data."""
        return tuple(BagFacts(b.path, b.episodes, b.steps,
                              sum(len(b.adjusted.get(how, ())) for how in GUESSED_LAST),
                              b.idle_speed, b.idle_on) for b in self.bags)

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
