"""Settings of the paper's tables and the validated specification of a reproduction.

The settings are the rows of Table 1 (Craft: full/partial observations × with/without sketch) and
of the Dial table (with/without sketch) of Lu et al., ICLR 2021, §4.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from ompn_ros.errors import OMPNError

Domain = Literal["craft", "dial"]
CRAFT_TASKS = ("makebed", "makeaxe", "makeshears")
EXTRAS = ("ksweep", "thresholds", "ablations", "ensemble", "distill", "online_lag")
DISTILL_WEIGHT = 1.0
"""``train.distill_weight`` of the ``distill`` extra's students: of 1 and 3, the weight with the higher
validation alignment on seeds 0 and 1 of Craft full (docs/experiments.md §35)."""
DEFAULT_EPISODES = {"craft": 500, "dial": 1400}  # Craft: per task; Dial: in total
DEFAULT_TEST_RATIO = 0.2
REPRODUCTION_ITERATIONS = {"craft": 200, "dial": 300}
"""The reproduction's fixed training length with the shipped configs (docs/experiments.md §5, §6).
``ompn_train`` stops early by default (``train.patience`` in ``config/train_<domain>.yaml``); the
reproduction pins these lengths and ``patience: 0`` so that the committed results stay reproducible."""
MEMBER_SEED_STRIDE = 1000
"""Ensemble member ``j`` of seed ``s`` trains with seed ``s + MEMBER_SEED_STRIDE * j`` (member 0 is
the seed's own run)."""


class ReproduceError(OMPNError, RuntimeError):
    """A stage of the reproduction cannot run (names the stage or the option and the cause)."""


@dataclass(frozen=True)
class Setting:
    """One row of the paper's Table 1."""

    name: str
    partial: bool = False
    sketch: bool = False


SETTINGS: dict[str, dict[str, Setting]] = {
    "craft": {
        s.name: s
        for s in (
            Setting("full_nosketch"),
            Setting("full_sketch", sketch=True),
            Setting("partial_nosketch", partial=True),
            Setting("partial_sketch", partial=True, sketch=True),
        )
    },
    "dial": {s.name: s for s in (Setting("nosketch"), Setting("sketch", sketch=True))},
}
PRIMARY = {"craft": "full_nosketch", "dial": "nosketch"}
ABLATIONS: dict[str, dict[str, Any]] = {
    "memory_paper": {"memory_update": "paper"},
    "memory_code": {"memory_update": "code"},
    "no_bottom_up": {"no_bottom_up": True},
    "no_top_down": {"no_top_down": True},
    "no_bottom_up_recurrence": {"no_bottom_up_recurrence": True},
    "no_done_loss": {"_train.no_done_loss": True},
}


@dataclass(frozen=True)
class RunSpec:
    """One training run: a setting, a seed (and ensemble member), an optional ablation.

    ``overrides`` set model fields, or training fields with a ``_train.`` prefix; ``tag`` names the
    ablation in the run directory; ``member`` > 0 is an extra ensemble member of ``seed``.
    """

    domain: str
    setting: Setting
    seed: int
    iterations: int | None = None
    overrides: dict[str, Any] = field(default_factory=dict)
    tag: str = ""
    member: int = 0
    reuse: bool = False
    skip_trained: bool = False

    def __post_init__(self) -> None:
        if self.domain not in SETTINGS or self.setting.name not in SETTINGS[self.domain]:
            raise ReproduceError(f"run: unknown setting {self.setting.name!r} for domain {self.domain!r}")
        if self.seed < 0 or self.member < 0:
            raise ReproduceError(f"run: seed and member must be >= 0, got {self.seed}, {self.member}")
        if self.iterations is not None and self.iterations < 1:
            raise ReproduceError(f"run: iterations must be >= 1, got {self.iterations}")

    @property
    def name(self) -> str:
        """The run directory's name: ``<setting><tag>_seed<seed>[_m<member>]``."""
        return f"{self.setting.name}{self.tag}_seed{self.seed}{f'_m{self.member}' if self.member else ''}"

    @property
    def train_seed(self) -> int:
        return self.seed + MEMBER_SEED_STRIDE * self.member


def _parse_list(
    text: str, known: Sequence[str], what: str, everything: Sequence[str], where: str = ""
) -> list[str]:
    names = [s for s in text.split(",") if s] or list(everything)
    unknown = [s for s in names if s not in known]
    if unknown:
        raise ReproduceError(f"unknown {what} {unknown}{where}; known: {sorted(known)}")
    return names


def parse_extras(text: str) -> set[str]:
    """``--extras``: ``all``, ``none`` or a comma list of :data:`EXTRAS`."""
    wanted = set(EXTRAS) if text == "all" else (set() if text == "none" else set(text.split(",")))
    if wanted - set(EXTRAS):
        raise ReproduceError(f"unknown extras {sorted(wanted - set(EXTRAS))}; known: {list(EXTRAS)}")
    return wanted


def parse_members(spec: str, names: Sequence[str]) -> dict[str, int]:
    """``--members``: ``'M'`` for every setting of the run, or ``'setting=M,...'`` (others get 1)."""
    text = spec.strip()
    if "=" not in text:
        try:
            count = int(text)
        except ValueError:
            raise ReproduceError(f"--members must be an integer M or SETTING=M pairs, got {spec!r}") from None
        per = {name: count for name in names}
    else:
        per = {name: 1 for name in names}
        for part in filter(None, (p.strip() for p in text.split(","))):
            name, _, value = part.partition("=")
            if name not in per:
                raise ReproduceError(
                    f"--members names {name!r}, which is not among the settings of this run {list(names)}"
                )
            try:
                per[name] = int(value)
            except ValueError:
                raise ReproduceError(f"--members {part!r}: the member count must be an integer") from None
    bad = {k: v for k, v in per.items() if v < 1}
    if bad:
        raise ReproduceError(f"--members must be >= 1 (1 = single models), got {bad}")
    return per


@dataclass(frozen=True)
class ReproduceSpec:
    """Everything one ``python -m lab.reproduce`` call does, validated before any stage runs."""

    domain: str
    settings: tuple[str, ...]
    seeds: int = 5
    episodes: int = 0
    data_seed: int = 0
    iterations: int | None = None
    test_ratio: float = DEFAULT_TEST_RATIO
    config: Path | None = None
    members: dict[str, int] = field(default_factory=dict)
    extras: frozenset[str] = frozenset(EXTRAS)
    work: Path = Path("runs")
    results: Path = Path("results")
    threads: int | None = None
    evaluate: Path | None = None
    reevaluate: bool = False
    skip_trained: bool = False
    merge: bool = False
    extras_only: bool = False
    ablations: tuple[str, ...] = tuple(ABLATIONS)
    ship: bool = False
    command: tuple[str, ...] = ()

    @classmethod
    def build(
        cls,
        domain: str,
        settings: str = "",
        extras: str = "all",
        members: str = "1",
        ablations: str = ",".join(ABLATIONS),
        **fields: Any,
    ) -> ReproduceSpec:
        """Parse the comma-list options and fill the domain defaults (episodes, work directory)."""
        if domain not in SETTINGS:
            raise ReproduceError(f"unknown domain {domain!r}; known: {sorted(SETTINGS)}")
        names = _parse_list(
            settings, list(SETTINGS[domain]), "settings", list(SETTINGS[domain]), f" for {domain}"
        )
        chosen = _parse_list(ablations, list(ABLATIONS), "ablations", [])
        fields["episodes"] = fields.get("episodes") or DEFAULT_EPISODES[domain]
        fields["work"] = fields.get("work") or Path("runs") / f"reproduce_{domain}"
        return cls(
            domain=domain,
            settings=tuple(names),
            extras=frozenset(parse_extras(extras)),
            members=parse_members(members, names),
            ablations=tuple(chosen),
            **fields,
        )

    def __post_init__(self) -> None:
        if self.seeds < 1:
            raise ReproduceError(f"--seeds must be >= 1, got {self.seeds}")
        if not 0.0 < self.test_ratio < 1.0:
            raise ReproduceError(f"--test-ratio must be in (0, 1), got {self.test_ratio}")
        if self.episodes < 1:
            raise ReproduceError(f"--episodes must be >= 1, got {self.episodes}")
