"""The reproduction's data: seeded demonstrations in rosbag2 files, read back, split by seed.

The bags go through the same reader (and episode cache) that ``ompn_train`` runs on users' bags;
the test split is held out before training and never trained on (Lu et al., ICLR 2021, §4 evaluate
on held-out demonstrations).
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lab.spec import CRAFT_TASKS, ReproduceError
from ompn_ros.app.collect import MANIFEST, collect, human_settings
from ompn_ros.data.cache import load_arrays
from ompn_ros.data.episode import Episode
from ompn_ros.data.reader import ReaderSpec
from sim_nodes.human import BOUNDARY_MODE

HUMAN_VARIANTS: dict[str, tuple[str, ...]] = {
    "human": (),
    "human_nopauses": ("pause_rate=0", "hesitation_rate=0"),
    "human_nodetours": ("overshoot_rate=0", "wrong_move_rate=0"),
    "human_boundaries": BOUNDARY_MODE,
}
"""Human-like demonstrators of the lab: the defaults, and the defaults without one perturbation
(docs/experiments.md §54), and pauses at subtask changes (§57)."""


def collect_bags(
    domain: str, partial: bool, episodes: int, seed: int, work: Path, demonstrator: str = "expert"
) -> Path:
    """Seeded demonstrations into ``work/bags/<domain>_<obs>[_<demonstrator>]/`` (reused when already
    complete).

    ``episodes`` is per task for Craft and in total for Dial.  ``demonstrator``: 'expert' or a key
    of :data:`HUMAN_VARIANTS` (the human-like demonstrator with those parameters).  O(episodes)
    rollouts.
    """
    human = demonstrator != "expert"
    changes = HUMAN_VARIANTS[demonstrator] if human else ()
    suffix = f"_{demonstrator}" if human else ""
    out = work / "bags" / f"{domain}_{'partial' if partial else 'full'}{suffix}"
    tasks = list(CRAFT_TASKS) if domain == "craft" else ["dial"]
    total = episodes * len(tasks) if domain == "craft" else episodes
    manifest_file = out / MANIFEST
    if manifest_file.is_file():
        manifest = json.loads(manifest_file.read_text())
        settings = manifest["settings"]
        if (
            manifest.get("totals", {}).get("episodes") == total
            and settings["seed"] == seed
            and settings.get("demonstrator", "expert") == ("human" if human else "expert")
            and (not human or settings.get("human") == human_settings(domain, changes).as_dict())
        ):
            print(f"   reusing {out} ({total} episodes)")
            return out
    collect(
        out,
        domain=domain,
        tasks=tasks,
        episodes=total,
        seed=seed,
        partial=partial,
        split_every=max(1, total // 4),
        overwrite=out.exists(),
        progress=sys.stderr.isatty(),
        human=human_settings(domain, changes) if human else None,
        command=[
            "ompn_collect",
            "--domain",
            domain,
            "--task",
            ",".join(tasks),
            "--episodes",
            str(total),
            "--seed",
            str(seed),
            *(["--partial"] if partial else []),
            *(["--demonstrator", "human"] if human else []),
            *[arg for change in changes for arg in ("--human", change)],
        ],
    )
    return out


def read_bags(domain: str, bags: Path) -> list[Episode]:
    """Episodes from the bags, through the cached reader that ``ompn_train`` uses."""
    arrays = load_arrays(bags, spec=ReaderSpec.for_domain(domain), cache_dir=bags.parent / ".cache")
    episodes = arrays.episodes()
    if not episodes:
        raise ReproduceError(f"read stage: no episodes in {bags}")
    return episodes


def held_out_split(
    episodes: Sequence[Episode], ratio: float, seed: int
) -> tuple[list[Episode], list[Episode]]:
    """Seeded split, stratified by task: (train pool, test).  Test episodes are never trained on.

    ``max(1, round(ratio · n))`` episodes of each task go to the test split.  O(N).
    """
    rng = np.random.default_rng([seed, 0x7E57])
    train: list[Episode] = []
    test: list[Episode] = []
    for task in sorted({ep.task for ep in episodes}):
        group = [ep for ep in episodes if ep.task == task]
        order = rng.permutation(len(group))
        n_test = max(1, round(ratio * len(group)))
        test.extend(group[i] for i in order[:n_test])
        train.extend(group[i] for i in order[n_test:])
    overlap = {(ep.task, ep.seed) for ep in train} & {(ep.task, ep.seed) for ep in test}
    if overlap:
        raise ReproduceError(f"split stage: {len(overlap)} episodes are in both train and test")
    return train, test


IDLE_TOLERANCE = 0.2
"""A Craft step is idle when no observation feature moves by this much (features are one-hot; the
human-like sensor noise has a standard deviation of 0.02)."""


def collapse_idle(ep: Episode, tol: float = IDLE_TOLERANCE, features: int | None = None
                  ) -> tuple[Episode, np.ndarray]:
    """(the episode without its idle steps, the kept steps): step t is idle when observation t + 1
    differs from observation t by less than ``tol`` in every feature (the first ``features`` only,
    when given): its action changed nothing.  The last step is always kept, and the final
    observation stays (docs/experiments.md §54)."""
    watched = ep.observations if features is None else ep.observations[:, :features]
    moved = np.abs(np.diff(watched, axis=0)).max(axis=1) >= tol
    moved[-1] = True
    kept = np.flatnonzero(moved)
    subtask = None if ep.subtask is None else ep.subtask[kept]
    short = Episode(np.concatenate([ep.observations[kept], ep.observations[-1:]]), ep.actions[kept], subtask,
                    ep.sketch, ep.task, ep.seed, ep.success)
    return short, kept
