"""Seeded expert demonstrations written as rosbag2 parts, without DDS (the engine of ``ompn_collect``).

``collect(out, domain=..., tasks=..., episodes=N, seed=S, split_every=M)`` writes
``out/part_000/ ...`` (one rosbag2 directory per part) and ``out/collect.json`` (command, seeds,
counts).  Episode ``i`` uses task ``tasks[i % len(tasks)]`` and seed :func:`episode_seed` ``(S, i)``.
Each part is written under a hidden temporary name and renamed when complete, so ``resume=True``
continues after the last complete part and never reads a half-written one.  Cost: one expert
episode per demonstration, O(N) episodes.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from ompn_ros import layout
from ompn_ros.app.errors import CollectError
from ompn_ros.data.episode import Episode, observation_copies
from ompn_ros.data.recorder.bag_writer import STORAGES, EpisodeBagWriter
from sim_nodes.registry import DEMONSTRATORS as DEMONSTRATORS  # ompn_collect's --demonstrator choices
from sim_nodes.registry import (
    DOMAINS,
    HumanLike,
    HumanLikeError,
    UnknownDomainError,
    check_task,
    derive_seed,
    expert_episode,
    parse_human,
)

MANIFEST = "collect.json"
Generator = Callable[[int, str, bool], Episode]


def episode_seed(seed: int, index: int) -> int:
    """Seed of episode ``index`` of a run seeded with ``seed``: ``sim_nodes.derive_seed(seed, index)``,
    the same as the sim nodes use, so ``ompn_collect --seed S`` and ``craft_sim seed:=S`` agree."""
    return derive_seed(int(seed), int(index))


def default_generator(domain: str, human: HumanLike | None = None) -> Generator:
    """The domain's demonstrator (``sim_nodes.registry.expert_episode``): the scripted expert, or
    the human-like one with the parameters ``human``."""
    if domain not in DOMAINS:
        raise CollectError(f"unknown domain '{domain}', expected one of {sorted(layout.DOMAINS)}")

    def generate(seed: int, task: str, partial: bool) -> Episode:
        return expert_episode(domain, seed, task=task, partial=partial, human=human)

    return generate


def human_settings(domain: str, items: Sequence[str]) -> HumanLike:
    """The human-like demonstrator's parameters of ``domain`` from ``NAME=VALUE`` items (a bad one:
    :class:`CollectError` naming it)."""
    try:
        return parse_human(domain, items)
    except HumanLikeError as exc:
        raise CollectError(str(exc)) from exc


def part_name(index: int) -> str:
    return f"part_{index:03d}"


@dataclass(frozen=True)
class _Plan:
    """The options of one collection: checked by :func:`_check`, recorded by :func:`_settings`."""

    domain: str
    tasks: Sequence[str]
    episodes: int
    seed: int
    storage: str
    split_every: int | None
    partial: bool
    human: HumanLike | None


def _settings(plan: _Plan) -> dict[str, Any]:
    settings: dict[str, Any] = {
        "domain": plan.domain,
        "tasks": list(plan.tasks),
        "episodes": plan.episodes,
        "seed": plan.seed,
        "storage": plan.storage,
        "split_every": plan.split_every,
        "partial": plan.partial,
    }
    if plan.human is not None:  # expert collections keep the settings (and resume) of earlier versions
        settings["demonstrator"] = "human"
        settings["human"] = plan.human.as_dict()
    return settings


def _prepare_output(out: Path, settings: dict[str, Any], resume: bool, overwrite: bool) -> dict[str, Any]:
    """Create/validate ``out``; returns the manifest to continue from."""
    manifest_file = out / MANIFEST
    fresh = {"settings": settings, "parts": [], "version": 1}
    if not out.exists() or (out.is_dir() and not any(out.iterdir())):
        out.mkdir(parents=True, exist_ok=True)
        return fresh
    if not out.is_dir():
        raise CollectError(f"output '{out}' exists and is not a directory")
    ours = manifest_file.is_file() or any(p.name.startswith("part_") for p in out.iterdir())
    if overwrite:
        if not ours:
            raise CollectError(
                f"output directory '{out}' exists and does not look like an ompn_collect "
                "output (no collect.json, no part_* directories); refusing to delete it"
            )
        shutil.rmtree(out)
        out.mkdir(parents=True)
        return fresh
    if not resume:
        raise CollectError(
            f"output directory '{out}' already exists; pass --overwrite to replace it "
            "or --resume to continue after its last complete part"
        )
    if not manifest_file.is_file():
        raise CollectError(f"cannot resume: '{manifest_file}' is missing")
    try:
        manifest = json.loads(manifest_file.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise CollectError(f"cannot resume: '{manifest_file}' is not valid JSON ({exc})") from exc
    old = manifest.get("settings", {})
    if old != settings:
        diff = {k: (old.get(k), v) for k, v in settings.items() if old.get(k) != v}
        raise CollectError(f"cannot resume '{out}': settings differ from the first run (old, new): {diff}")
    for tmp in out.glob(".part_*.tmp"):
        shutil.rmtree(tmp)  # a part interrupted mid-write
    done = {p["name"] for p in manifest["parts"]}
    for part in out.glob("part_*"):
        if part.name not in done:
            shutil.rmtree(part)  # renamed but not recorded: redo it
    return dict(manifest)


def _write_manifest(out: Path, manifest: dict[str, Any]) -> None:
    tmp = out / f".{MANIFEST}.tmp"
    tmp.write_text(json.dumps(manifest, indent=1), encoding="utf-8")
    tmp.replace(out / MANIFEST)


def _check(plan: _Plan, resume: bool, overwrite: bool) -> None:
    """Raise :class:`CollectError` naming the first bad option."""
    domain, tasks, episodes, seed = plan.domain, plan.tasks, plan.episodes, plan.seed
    storage, split_every, partial = plan.storage, plan.split_every, plan.partial
    if domain not in layout.DOMAINS:
        raise CollectError(f"unknown domain '{domain}', expected one of {sorted(layout.DOMAINS)}")
    if seed < 0:
        raise CollectError(f"--seed must be >= 0, got {seed}")
    if storage not in STORAGES:
        raise CollectError(f"unknown storage '{storage}', expected one of {STORAGES}")
    if episodes < 1:
        raise CollectError(f"--episodes must be >= 1, got {episodes}")
    if split_every is not None and split_every < 1:
        raise CollectError(f"--split-every must be >= 1, got {split_every}")
    if not tasks:
        raise CollectError("--task needs at least one task name")
    for task in tasks:
        try:
            check_task(domain, task)
        except UnknownDomainError as exc:
            raise CollectError(str(exc)) from exc
    if partial and domain != "craft":
        raise CollectError("--partial (egocentric observations) applies to --domain craft only")
    if resume and overwrite:
        raise CollectError("--resume and --overwrite exclude each other")


def _write_part(
    out: Path, k: int, indices: list[int], plan: _Plan, generator: Generator, bar: Any
) -> dict[str, Any]:
    """Write the episodes ``indices`` as part ``k``: in a temporary directory, moved into place when
    complete.  The bag directory has its final name from the start, because rosbag2 names the storage
    file after it (``part_000/part_000.mcap``)."""
    tmp = out / f".{part_name(k)}.tmp"
    if tmp.exists():
        shutil.rmtree(tmp)
    tmp.mkdir()
    bag = tmp / part_name(k)
    record: dict[str, Any] = {
        "name": part_name(k),
        "episodes": indices,
        "seeds": [],
        "tasks": [],
        "steps": 0,
        "successes": 0,
    }
    start = time.perf_counter()
    dom = layout.DOMAINS[plan.domain]
    with EpisodeBagWriter(bag, dom, storage=plan.storage, first_episode_index=indices[0]) as writer:
        for i in indices:
            ep_seed = episode_seed(plan.seed, i)
            task = plan.tasks[i % len(plan.tasks)]
            episode = generator(ep_seed, task, plan.partial)
            writer.write_episode(episode, episode_index=i)
            record["seeds"].append(ep_seed)
            record.setdefault("episode_seeds", []).append(int(episode.seed))
            record["tasks"].append(task)
            record["steps"] += episode.length
            record["successes"] += int(episode.success)
            if plan.human is not None:
                copies = observation_copies(episode)
                for key, count in (("dropped_observations", 0), ("duplicated_observations", 2)):
                    record[key] = record.get(key, 0) + int(sum(copies == count))
            bar.update(1)
    record["messages"] = writer.stats.total_messages
    record["seconds"] = round(time.perf_counter() - start, 3)
    bag.rename(out / part_name(k))
    tmp.rmdir()
    return record


def _totals(parts: list[dict[str, Any]]) -> dict[str, int]:
    return {
        "parts": len(parts),
        "episodes": sum(len(p["episodes"]) for p in parts),
        "steps": sum(p["steps"] for p in parts),
        "successes": sum(p["successes"] for p in parts),
        "messages": sum(p["messages"] for p in parts),
    }


def collect(
    out: str | Path,
    *,
    domain: str,
    tasks: Sequence[str],
    episodes: int,
    seed: int = 0,
    storage: str = "mcap",
    split_every: int | None = None,
    partial: bool = False,
    resume: bool = False,
    overwrite: bool = False,
    generator: Generator | None = None,
    progress: bool = True,
    command: Sequence[str] | None = None,
    human: HumanLike | None = None,
) -> dict[str, Any]:
    """Generate ``episodes`` demonstrations and write them as bag parts under ``out``.

    ``human``: the human-like demonstrator with these parameters instead of the expert (its dropped
    observation messages are absent from the bag, its duplicated ones written twice).  Returns the
    manifest (also written to ``out/collect.json``).
    """
    plan = _Plan(domain, tasks, episodes, seed, storage, split_every, partial, human)
    _check(plan, resume, overwrite)
    out = Path(out)
    manifest = _prepare_output(out, _settings(plan), resume, overwrite)
    manifest["command"] = list(command if command is not None else sys.argv)
    generate = generator or default_generator(domain, human)
    per_part = split_every or episodes
    n_parts = (episodes + per_part - 1) // per_part
    done = {p["name"] for p in manifest["parts"]}
    todo = [k for k in range(n_parts) if part_name(k) not in done]
    remaining = sum(min(per_part, episodes - k * per_part) for k in todo)
    bar = tqdm(
        total=episodes,
        initial=episodes - remaining,
        unit="ep",
        disable=not progress,
        desc=f"{domain} -> {out}",
    )
    try:
        for k in todo:
            indices = list(range(k * per_part, min((k + 1) * per_part, episodes)))
            manifest["parts"].append(_write_part(out, k, indices, plan, generate, bar))
            manifest["parts"].sort(key=lambda p: p["name"])
            _write_manifest(out, manifest)
    finally:
        bar.close()
    manifest["totals"] = _totals(manifest["parts"])
    _write_manifest(out, manifest)
    return manifest
