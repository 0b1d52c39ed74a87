"""The "own data" sections of ``results/README.md``: ``own_data.json`` and ``own_robot.json``.

* ``own_data.json`` (:class:`OwnDataDoc`, written by :mod:`lab.own_data`): one row
  per arm of the studies on our own Craft and Dial bags (labels hidden, final observation removed,
  training length), scored on held-out test episodes.
* ``own_robot.json`` (:class:`OwnRobotDoc`): a stranger's arm recorded with the Dial simulator's
  robot profile (docs/experiments.md §25), one row per observation choice.

Metrics are fractions in the files and percentages in the tables.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypedDict

OWN_DATA = "own_data.json"
OWN_ROBOT = "own_robot.json"


class OwnDataRow(TypedDict, total=False):
    """One arm: what was trained and its held-out scores (online = the causal detector replayed)."""

    arm: str
    study: str  # "labels" | "final_observation" | "length"
    domain: str
    observation: str  # "full" | "partial"
    labels: str  # "auto" | "none" (hidden from training and calibration)
    length: str  # "patience" | "fixed"
    bags: str  # "complete" | "drop_last_step" | "duplicate" | "blank" | "extrapolate"
    seed: int
    iterations: int
    best_iteration: int
    stopped_early: bool
    selection: str  # the criterion that picked the checkpoint
    checkpoint: str  # "best" | "last" (a scored checkpoint of an existing run)
    train_seconds: float | None
    train_episodes: int
    val_episodes: int
    test_episodes: int
    offline_f1_1: float
    offline_align: float
    online_f1_1: float  # the detector tuned on the validation labels
    online_align: float
    label_free_online_f1_1: float  # the detector calibrated without labels
    label_free_online_align: float
    candidates_trained: int  # train.candidates when > 1: the best of that many initialisations
    demonstrator: str  # "expert" | "human" (absent: expert)
    restart: bool  # False: trained with the restart rule off (absent: as the shipped config)
    restarts: int  # how many times the restart rule started the run (or a candidate) again
    restart_abandoned: int  # runs (or candidates) the earlier rule restarted, abandoning the first


class OwnDataDoc(TypedDict):
    meta: dict[str, Any]
    rows: list[OwnDataRow]


class OwnRobotRow(TypedDict):
    observation: str
    obs_dim: int
    train_episodes: int
    test_episodes: int
    online_f1_1: float
    online_align: float
    offline_f1_1: float
    offline_align: float
    live_f1_1: float | None
    live_align: float | None


class OwnRobotDoc(TypedDict):
    meta: dict[str, Any]
    rows: list[OwnRobotRow]


def pct(value: float | None) -> str:
    """A fraction in % with one decimal; a dash when absent."""
    return "–" if value is None else f"{100 * value:.1f}"


def pair(f1: float | None, align: float | None) -> str:
    """``F1@1 / alignment`` in %."""
    return f"{pct(f1)} / {pct(align)}"


def gap(a: float | None, b: float | None) -> str:
    """``a − b`` in percentage points, signed."""
    return "–" if a is None or b is None else f"{100 * (a - b):+.1f}"


def gaps(a: tuple[float | None, float | None], b: tuple[float | None, float | None]) -> str:
    """``"ΔF1 / Δalign"`` of the pair ``a`` against the pair ``b`` (F1@1, alignment)."""
    return f"{gap(a[0], b[0])} / {gap(a[1], b[1])}"


def _candidates(row: OwnDataRow) -> int:
    return int(row.get("candidates_trained", 1))


def _best_of(row: OwnDataRow) -> str:
    n = _candidates(row)
    return f", best of {n}" if n > 1 else ""


def _setting(row: OwnDataRow) -> str:
    name = "Craft" if row["domain"] == "craft" else "Dial"
    obs = f" {row['observation']}" if row["domain"] == "craft" else ""
    human = {"expert": "", "human": ", human-like"}.get(row.get("demonstrator", "expert"),
                                                        f", {row.get('demonstrator')}")
    last = ", last checkpoint" if row.get("checkpoint") == "last" else ""
    rule = ", no restart rule" if row.get("restart") is False else ""
    if row.get("restart_abandoned"):
        rule = ", earlier restart rule"  # the first initialisation abandoned, not compared
    return f"{name}{obs}{human}, seed {row['seed']}{_best_of(row)}{last}{rule}"


def _twin(row: OwnDataRow) -> tuple[str, int, int, str, bool]:
    """What pairs an arm with its complete-bags arm: domain, seed, the candidates trained, the
    demonstrator and the restart rule."""
    return (row["domain"], row["seed"], _candidates(row), row.get("demonstrator", "expert"),
            row.get("restart", True))


def _iterations(row: OwnDataRow) -> str:
    return f"{row['iterations']} ({row['best_iteration']})"


def _head(*columns: str) -> list[str]:
    """A markdown table's header row and separator."""
    return ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]


def json_section(results_dir: Path, name: str, title: str, intro: Callable[[dict[str, Any]], str],
                 columns: Sequence[str], lines: Callable[[dict[str, Any]], Iterable[str]],
                 level: int = 2) -> list[str]:
    """A README section from the results file ``name``: the heading ``title``, ``intro(meta)``, and a
    table of ``columns`` whose rows are ``lines(doc)``; nothing when the file is absent."""
    path = results_dir / name
    if not path.is_file():
        return []
    doc = json.loads(path.read_text(encoding="utf-8"))
    text = [f"{'#' * level} {title}", "", intro(doc["meta"]), "", *_head(*columns), *lines(doc)]
    return ["\n".join(text) + "\n"]


def _scores(row: Mapping[str, Any], kind: str) -> str:
    """``F1@1 / alignment`` in % of one detector: ``online``, ``offline`` or ``live``."""
    return pair(row[f"{kind}_f1_1"], row[f"{kind}_align"])


_DELTA_COLUMNS = (
    "online F1@1 / align", "Δ online vs complete", "offline F1@1 / align", "Δ offline vs complete"
)
"""The score and gap columns of the final-observation table and of its means."""


def _labels_table(rows: list[OwnDataRow]) -> list[str]:
    lines = _head("setting", "iterations (best)", "online, label-tuned det.", "online, label-free det.",
                  "gap F1 / align", "offline")
    for r in rows:
        tuned, free = (
            (r["online_f1_1"], r["online_align"]),
            (r["label_free_online_f1_1"], r["label_free_online_align"]),
        )
        lines.append(
            f"| {_setting(r)} | {_iterations(r)} | {pair(*tuned)} | {pair(*free)} | "
            f"{gaps(free, tuned)} | {_scores(r, 'offline')} |"
        )
    return lines


def _final_table(rows: list[OwnDataRow]) -> list[str]:
    lines = _head("setting", "training bags", *_DELTA_COLUMNS)
    complete = {_twin(r): r for r in rows if r["bags"] == "complete"}
    for r in rows:
        ref = complete.get(_twin(r))
        d_on = d_off = "–"
        if ref is not None and r is not ref:
            d_on, d_off = (
                gaps((r[f"{k}_f1_1"], r[f"{k}_align"]), (ref[f"{k}_f1_1"], ref[f"{k}_align"]))  # type: ignore[literal-required]
                for k in ("online", "offline")
            )
        lines.append(
            f"| {_setting(r)} | {r['bags']} | {_scores(r, 'online')} | {d_on} | "
            f"{_scores(r, 'offline')} | {d_off} |"
        )
    return lines + _final_means(rows)


def _mean_row(label: str, pairs: list[tuple[OwnDataRow, OwnDataRow]]) -> str:
    """One line of :func:`_final_means`: the means of ``(handled, complete)`` pairs and of their gaps
    (a dash for the complete arms themselves, paired with themselves)."""
    def mean(rows: list[OwnDataRow], key: str) -> float:
        values: list[float] = [float(r[key]) for r in rows]  # type: ignore[literal-required, misc]
        return sum(values) / len(values)

    cells = []
    for kind in ("online", "offline"):
        f1, align = f"{kind}_f1_1", f"{kind}_align"
        handled = [h for h, _ in pairs]
        complete = [c for _, c in pairs]
        means = (mean(handled, f1), mean(handled, align))
        same = all(h is c for h, c in pairs)
        cells += [pair(*means), "–" if same else gaps(means, (mean(complete, f1), mean(complete, align)))]
    return f"| {label} | {cells[0]} | {cells[1]} | {cells[2]} | {cells[3]} |"


def _seed_span(pairs: list[tuple[OwnDataRow, OwnDataRow]]) -> str:
    seeds = sorted(h["seed"] for h, _ in pairs)
    contiguous = seeds == list(range(seeds[0], seeds[-1] + 1))
    return f"seeds {seeds[0]}–{seeds[-1]}" if contiguous else "seeds " + ", ".join(map(str, seeds))


def _final_means(rows: list[OwnDataRow]) -> list[str]:
    """Per domain, handling and candidates trained, with two seeds or more: the mean over the seeds
    that have a complete-bags arm too, and the mean gap (the same seeds' complete arms), in percentage
    points; the complete arms' own means come first."""
    complete = {_twin(r): r for r in rows if r["bags"] == "complete"}
    groups: dict[tuple[str, str, str], list[tuple[OwnDataRow, OwnDataRow]]] = {}
    for r in rows:
        ref = complete.get(_twin(r))
        if ref is not None:  # complete arms pair with themselves: their means, no gap
            rule = ", no restart rule" if r.get("restart") is False else ""
            groups.setdefault((r["domain"], r["bags"], _best_of(r) + rule), []).append((r, ref))
    means = [
        _mean_row(f"{'Craft full' if domain == 'craft' else 'Dial'}, {bags}{best}, {len(pairs)} seeds "
                  f"({_seed_span(pairs)})", pairs)
        for (domain, bags, best), pairs in groups.items() if len(pairs) >= 2
    ]
    if not means:
        return []
    return ["", "Means over seeds (each against the complete arm of the same seed):", "",
            *_head("setting", *_DELTA_COLUMNS), *means]


def _length_table(rows: list[OwnDataRow]) -> list[str]:
    lines = _head("setting", "length", "iterations reached", "best iteration", "online F1@1 / align",
                  "offline F1@1 / align")
    for r in rows:
        lines.append(
            f"| {_setting(r)} | {r['length']} | {r['iterations']} | {r['best_iteration']} | "
            f"{_scores(r, 'online')} | {_scores(r, 'offline')} |"
        )
    return lines


STUDIES = (
    ("labels", "Labels hidden from training and calibration", _labels_table),
    (
        "final_observation",
        "Training bags without the final observation (test episodes complete)",
        _final_table,
    ),
    ("length", "Early stopping against the reproduction's fixed length", _length_table),
    ("demonstrator", "Human-like demonstrations (the same protocols; test episodes human-like too)",
     _final_table),
)


def _meta_lines(meta: dict[str, Any]) -> list[str]:
    lines = [
        f"Held-out test episodes only; F1@1 / alignment in %. Made by `{' '.join(meta.get('command', []))}`"
    ]
    lines[0] += f" on {meta['date']}" if meta.get("date") else ""
    lines[0] += (
        f" ({meta['cpu']}, {meta.get('threads', 1)} torch thread per run)." if meta.get("cpu") else "."
    )
    episodes = meta.get("episodes", {})
    if episodes:
        lines += [
            "",
            "Episodes (train / validation / test): "
            + "; ".join(f"{name} {e['train']} / {e['val']} / {e['test']}" for name, e in episodes.items())
            + ".",
        ]
    for note in meta.get("notes", []):
        lines += ["", str(note)]
    return lines


def own_data_markdown(doc: OwnDataDoc, level: int = 2) -> str:
    """The three study tables of ``own_data.json``."""
    head, sub = "#" * level, "#" * (level + 1)
    lines = [
        f"{head} Own data: labels, bags as robots log them, training length",
        "",
        *_meta_lines(doc["meta"]),
    ]
    for study, title, render in STUDIES:
        rows = [r for r in doc["rows"] if r["study"] == study]
        if rows:
            lines += ["", f"{sub} {title}", "", *render(rows)]
    return "\n".join(lines) + "\n"


def own_robot_markdown(doc: OwnRobotDoc, level: int = 2) -> str:
    """The table of ``own_robot.json``: one row per observation choice."""
    head = "#" * level
    meta = doc["meta"]
    command = meta.get("command")
    lines = [
        f"{head} Own robot: proprioception only (Dial, robot profile)",
        "",
        "F1@1 / alignment in % on held-out test episodes; live = through `ompn_node` over ROS.",
    ]
    if command:
        lines[-1] += f" Made by `{' '.join(command) if isinstance(command, list) else command}`."
    lines += ["", *_head("observation", "obs dim", "train / test episodes", "online", "offline", "live")]
    for r in doc["rows"]:
        lines.append(
            f"| {r['observation']} | {r['obs_dim']} | {r['train_episodes']} / {r['test_episodes']} | "
            f"{_scores(r, 'online')} | {_scores(r, 'offline')} | {_scores(r, 'live')} |"
        )
    return "\n".join(lines) + "\n"


def own_markdown(results_dir: Path) -> list[str]:
    """The own-data and own-robot sections of the results directory (those whose file exists)."""
    parts: list[str] = []
    data_file, robot_file = results_dir / OWN_DATA, results_dir / OWN_ROBOT
    if data_file.is_file():
        parts.append(own_data_markdown(json.loads(data_file.read_text(encoding="utf-8"))))
    if robot_file.is_file():
        parts.append(own_robot_markdown(json.loads(robot_file.read_text(encoding="utf-8"))))
    return parts


__all__ = [
    "OWN_DATA",
    "OWN_ROBOT",
    "OwnDataDoc",
    "OwnRobotDoc",
    "own_data_markdown",
    "own_markdown",
    "own_robot_markdown",
]
