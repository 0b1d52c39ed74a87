"""The "Boundary head" sections of ``results/README.md``, from ``boundary_head.json``
(:mod:`lab.boundary_head`) and ``head_duration.json`` (:mod:`lab.head_duration`).

Metrics are fractions in the file and percentages in the table; delays in steps.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from .report_own import json_section, pair, pct

HEAD = "boundary_head.json"
HEAD_DURATION = "head_duration.json"


def _figures(means: dict[str, float] | None, f1: str = "f1_tol1", align: str = "align") -> str:
    """F1@1 / alignment, mean delay and share at the episode end of one online detector ('–': none)."""
    if means is None:
        return "–"
    return (f"{pair(means[f1], means[align])}, {means['delay_mean']:.1f} steps, "
            f"{pct(means['at_end_share'])} % at end")


def _online(means: dict[str, float] | None) -> str:
    return _figures(means, "online_f1_1", "online_align")


def _line(row: dict[str, Any]) -> str:
    means = row["means"]
    bundled = means["bundled"]
    return (f"| {row['family']} | {row['role']} | {row['runs']} | "
            f"{pair(means['offline']['f1_1'], means['offline']['align'])} | "
            f"{pair(bundled['f1_1'], bundled['align'])} | {_online(means['decoder_budget'])} | "
            f"{_online(means['head_labels'])} | {_online(means['head_topk'])} | {_chosen(means['chosen'])} |")


def _chosen(means: dict[str, float] | None) -> str:
    if means is None:
        return "–"
    return f"{pair(means['f1_1'], means['align'])} (head in {int(means['head_runs'])})"


def _intro(meta: dict[str, Any]) -> str:
    return (f"Made by `{' '.join(meta['command'])}` on {meta['date']}: a causal boundary head (an MLP over "
            f"the last {meta['window']} steps of the model's outputs, trained on each run's training "
            f"episodes; lag at most {meta['max_lag']} steps) against the run's own detectors, scored on "
            f"{meta['held_out']}. *offline*: the paper's detector of the domain (Top-K on Craft, the "
            "automatic threshold on Dial); *bundled*: the detector `ompn_train` bundled with the run "
            "when it was trained, before `ompn_train` fitted a head too (§52); *decoder ≤ 6*: Craft's "
            "duration decoder tuned on validation within the delay budget; *head, labels*: the head "
            "trained on the true boundaries; *head, Top-K*: trained on the model's own offline "
            "segmentation; *chosen on validation*: per run, the head (labels) where its validation "
            "alignment beats the bundled detector's, else the bundled detector, with the number of runs "
            "that chose the head. Design rows set the head; the "
            "others were kept out (docs/experiments.md §51). Means, F1@1 / alignment in %, then the mean "
            "delay of inner boundaries and the share published only at the episode end.")


def head_markdown(results_dir: Path, level: int = 2) -> list[str]:
    """The boundary-head table, when ``boundary_head.json`` exists."""
    return json_section(results_dir, HEAD, "Boundary head: a learned causal detector", _intro,
                        ("family", "role", "runs", "offline", "bundled", "decoder ≤ 6", "head, labels",
                         "head, Top-K", "chosen on validation"),
                        lambda doc: (_line(row) for row in doc["families"]), level)


def _duration_line(row: dict[str, Any]) -> str:
    means = row["means"]
    return (f"| {row['family']} | {row['role']} | {row['runs']} | "
            f"{pair(means['offline']['f1_tol1'], means['offline']['align'])} | "
            f"{pair(means['threshold']['f1_tol1'], means['threshold']['align'])} | "
            f"{_figures(means['previous'])} | {_figures(means['head_hsmm'])} | "
            f"{_figures(means['head_hsmm_any_delay'])} | {_figures(means['now'])} "
            f"(head_hsmm in {int(means['now_head_hsmm_runs']['runs'])}) |")


def _duration_intro(meta: dict[str, Any]) -> str:
    return (f"Made by `{' '.join(meta['command'])}` on {meta['date']}: the duration decoder over the "
            "boundary head (mode `head_hsmm`, docs/design.md) on the runs of the own-data study, trained by "
            "`ompn_train` with their head, scored through the node's segmenter on each run's held-out test "
            "episodes. "
            "*offline*: the run's Top-K (Craft) or automatic threshold (Dial); *threshold*: the run's "
            "threshold detector tuned on its validation labels; *previous*: the detector "
            "`ompn_train` chose before `head_hsmm` existed (threshold, `hsmm` or `head`); *head_hsmm*: its "
            f"threshold tuned on validation ({meta['budget']}); *no budget*: the same without the delay "
            "budget; *now*: `ompn_train`'s choice today, with the "
            f"number of runs that chose `head_hsmm`. Designed on {meta['design']}; every other row was kept "
            "out (docs/experiments.md §53). Means, F1@1 / alignment in %, then the mean delay of inner "
            "boundaries and the share published only at the episode end.")


def head_duration_markdown(results_dir: Path, level: int = 2) -> list[str]:
    """The table of mode 'head_hsmm', when ``head_duration.json`` exists."""
    return json_section(results_dir, HEAD_DURATION, "Boundary head: the duration decoder over it",
                        _duration_intro,
                        ("family", "role", "runs", "offline", "threshold", "previous", "head_hsmm",
                         "head_hsmm, no budget", "now"),
                        lambda doc: (_duration_line(row) for row in doc["families"]), level)


__all__ = ["HEAD", "HEAD_DURATION", "head_duration_markdown", "head_markdown"]
