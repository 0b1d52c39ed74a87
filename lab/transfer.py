"""The transfer table: each default chosen by tuning, on the data family it was tuned on and on
families it never saw (``results/transfer.json``, a section of ``results/README.md``).

Built from the arms of :mod:`lab.own_data` already in ``results/own_data.json`` (held-out test
episodes, one row per training run), so it needs no training of its own.  A *check* compares, over
the same seeds, the arms run with a default against the arms without it (its reference), on one
family of data:

* ``final_observation``: bags without the observation after the last command, read with the
  domain's preset (Craft ``blank`` with the best of two initialisations, Dial ``extrapolate`` until
  it was replaced by ``auto``, whose rows come from ``final_auto.json``), against complete bags of
  the same demonstrations, one run each;
* ``restart rule``: the same runs with the rule and without it (``train.restart_at: 0``);
* ``demonstrator``: human-like demonstrations against the expert's, complete bags (not a default:
  how much a user's teleoperated data costs, goal "human-like within 5 points");
* from the lab's studies: the detector's selection rule, ``final_observation: auto``, the
  agreement warm-up (against each family's own best warm-up) and the decoder's delay budget.

Families: Craft and Dial, expert and human-like demonstrations, full and partial observation,
complete and stripped bags.

A default *holds* on a family when no figure (offline and online F1@1 and alignment, means over
the seeds) is more than :data:`TOLERANCE` points below its reference.  The families each default was
tuned on, and the ones kept out of every tuning, are named in :data:`CHECKS`.  O(rows · checks).
"""

from __future__ import annotations

import itertools
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .report import write_readme
from .report_final_auto import FINAL_AUTO
from .report_head import HEAD_DURATION
from .report_own import OWN_DATA
from .report_selection import SELECTION
from .report_transfer import BUDGET, TRANSFER, WARMUP

TOLERANCE = 0.02
"""The largest loss (a fraction; 2 points) a default may show where it was not tuned."""
FIGURES = ("offline_f1_1", "offline_align", "online_f1_1", "online_align")

Row = dict[str, Any]
Select = Callable[[Row], bool]


def arm(domain: str, bags: str, demonstrator: str, candidates: int = 1, restart: bool = True,
        observation: str = "full") -> Select:
    """Rows of one kind of arm."""
    return lambda r: (
        r["domain"] == domain
        and r["observation"] == observation
        and r["bags"] == bags
        and r.get("demonstrator", "expert") == demonstrator
        and int(r.get("candidates_trained", 1)) == candidates
        and bool(r.get("restart", True)) == restart
        and r["study"] in ("final_observation", "demonstrator")
    )


@dataclass(frozen=True)
class Check:
    """One default (or family shift) on one family: the arms with it against the arms without."""

    default: str
    tuned_on: str
    family: str
    kept_out: str
    seeds: tuple[int, ...]
    with_default: Select
    reference: Select
    reference_name: str


CRAFT_SEEDS, DIAL_SEEDS = tuple(range(10, 15)), tuple(range(5, 10))
CHECKS = (
    Check("final_observation: blank, best of 2 (Craft)", "Craft full, expert, seeds 0–9",
          "Craft full, expert", "seeds 10–14", CRAFT_SEEDS,
          arm("craft", "blank", "expert", 2), arm("craft", "complete", "expert"), "complete bags, one run"),
    Check("final_observation: blank, best of 2 (Craft)", "Craft full, expert, seeds 0–9",
          "Craft full, human-like", "the family", CRAFT_SEEDS,
          arm("craft", "blank", "human", 2), arm("craft", "complete", "human"), "complete bags, one run"),
    Check("final_observation: blank, best of 2 (Craft)", "Craft full, expert, seeds 0–9",
          "Craft partial, human-like", "the family", CRAFT_SEEDS,
          arm("craft", "blank", "human", 2, observation="partial"),
          arm("craft", "complete", "human", observation="partial"), "complete bags, one run"),
    Check("final_observation: extrapolate (Dial's preset before auto)", "Dial, expert, seeds 0–4",
          "Dial, expert", "seeds 5–9", DIAL_SEEDS,
          arm("dial", "extrapolate", "expert"), arm("dial", "complete", "expert"), "complete bags"),
    Check("final_observation: extrapolate (Dial's preset before auto)", "Dial, expert, seeds 0–4",
          "Dial, human-like", "the family", DIAL_SEEDS,
          arm("dial", "extrapolate", "human"), arm("dial", "complete", "human"), "complete bags"),
    Check("restart rule: below 0.7 at iteration 120 (Craft)", "Craft with a sketch, expert, seeds 0–4",
          "Craft full, human-like, the runs it restarted", "the family", (11, 12),
          arm("craft", "complete", "human"), arm("craft", "complete", "human", restart=False),
          "the same seeds without the rule"),
    Check("restart rule: below 0.7 at iteration 120 (Craft)", "Craft with a sketch, expert, seeds 0–4",
          "Craft partial, human-like, the runs it restarted", "the family", CRAFT_SEEDS,
          arm("craft", "complete", "human", observation="partial"),
          arm("craft", "complete", "human", restart=False, observation="partial"),
          "the same seeds without the rule"),
    Check("demonstrator: human-like against expert (Craft)", "–", "Craft full, complete bags",
          "the family", CRAFT_SEEDS,
          arm("craft", "complete", "human"), arm("craft", "complete", "expert"), "expert demonstrations"),
    Check("demonstrator: human-like against expert (Craft partial)", "–", "Craft partial, complete bags",
          "the family", CRAFT_SEEDS,
          arm("craft", "complete", "human", observation="partial"),
          arm("craft", "complete", "expert", observation="partial"), "expert demonstrations"),
    Check("demonstrator: human-like against expert (Dial)", "–", "Dial, complete bags",
          "the family", DIAL_SEEDS,
          arm("dial", "complete", "human"), arm("dial", "complete", "expert"), "expert demonstrations"),
)


def _means(rows: Sequence[Row]) -> dict[str, float]:
    return {k: sum(float(r[k]) for r in rows) / len(rows) for k in FIGURES}


def evaluate(check: Check, rows: Sequence[Row]) -> Row | None:
    """The check's row: means over the seeds both sides have, the gap per figure, the verdict; None
    when no seed has both."""
    mine = {int(r["seed"]): r for r in rows if check.with_default(r) and int(r["seed"]) in check.seeds}
    ref = {int(r["seed"]): r for r in rows if check.reference(r) and int(r["seed"]) in check.seeds}
    seeds = sorted(set(mine) & set(ref))
    if not seeds:
        return None
    with_default = _means([mine[s] for s in seeds])
    reference = _means([ref[s] for s in seeds])
    gap = {k: with_default[k] - reference[k] for k in FIGURES}
    worst = min(gap.values())
    earlier = sum(int(side[s].get("restart_abandoned", 0)) for side in (mine, ref) for s in seeds)
    return {
        **({"earlier_restart_rule": earlier} if earlier else {}),
        "default": check.default, "tuned_on": check.tuned_on, "family": check.family,
        "kept_out_of_tuning": check.kept_out, "seeds": seeds, "reference": check.reference_name,
        "with_default": with_default, "without": reference, "gap": gap,
        "holds": worst >= -TOLERANCE,
    }


def detector_rows(results: Path) -> list[Row]:
    """The online detector's selection rule on the families kept out of its choice, against the
    previous rule on the same checkpoints (``detector_selection.json``; none when it is absent)."""
    path = results / SELECTION
    if not path.is_file():
        return []
    rows = []
    for family in json.loads(path.read_text(encoding="utf-8"))["families"]:
        if family["role"] != "kept out":
            continue
        new, old = family["means"]["one_se"], family["means"]["previous"]
        mine = {"online_f1_1": float(new["f1_1"]), "online_align": float(new["align"])}
        ref = {"online_f1_1": float(old["f1_1"]), "online_align": float(old["align"])}
        gap = {k: mine[k] - ref[k] for k in mine}
        offline = dict.fromkeys(("offline_f1_1", "offline_align"))  # the rule is online only
        rows.append({
            "default": "detector selection: one standard error", "tuned_on": "no free parameter",
            "family": family["family"], "kept_out_of_tuning": "the family",
            "seeds": sorted({int(a["arm"].rsplit("seed", 1)[1]) for a in family["arms"]}),
            "reference": "the previous rule, same checkpoints", "with_default": {**offline, **mine},
            "without": {**offline, **ref},
            "gap": gap, "holds": min(gap.values()) >= -TOLERANCE,
        })
    return rows


def study_rows(results: Path, name: str, sides: tuple[str, str], figures: Sequence[str],
               describe: Callable[[Row], Row]) -> list[Row]:
    """One row per family of the lab study file ``name`` (none when it is absent): the means under
    ``sides`` (the default's key, the reference's) compared on ``figures`` (the others shown as –);
    ``describe(family)`` gives the row's ``default``, ``tuned_on``, ``kept_out_of_tuning`` and
    ``reference``."""
    path = results / name
    if not path.is_file():
        return []
    rows = []
    for family in json.loads(path.read_text(encoding="utf-8"))["families"]:
        mine, ref = (family["means"][side] for side in sides)
        gap = {k: float(mine[k]) - float(ref[k]) for k in figures}
        rows.append({
            **describe(family), "family": family["family"], "seeds": list(family["seeds"]),
            "with_default": {k: float(mine[k]) if k in figures else None for k in FIGURES},
            "without": {k: float(ref[k]) if k in figures else None for k in FIGURES},
            "gap": gap, "holds": min(gap.values()) >= -TOLERANCE,
        })
    return rows


def final_auto_rows(results: Path) -> list[Row]:
    """``final_observation: auto`` (Dial) against complete bags (``final_auto.json``)."""
    return study_rows(results, FINAL_AUTO, ("auto", "complete"), FIGURES, lambda family: {
        "default": "final_observation: auto, extrapolate or duplicate (Dial)",
        "tuned_on": "no free parameter (the options: Dial expert seeds 0–4, human-like seeds 5–7)",
        "kept_out_of_tuning": family["kept_out_of_tuning"], "reference": "complete bags"})


def _span(values: Sequence[int]) -> str:
    """``"40–160"`` for evenly spaced values, ``"0"`` for one, ``"0, 40"`` otherwise."""
    even = len(values) > 2 and len({b - a for a, b in itertools.pairwise(values)}) == 1
    return f"{values[0]}–{values[-1]}" if even else ", ".join(map(str, values))


def warmup_rows(results: Path) -> list[Row]:
    """``agreement_warmup`` (label-free checkpoint selection) against the warm-up the family's own
    validation labels choose (``agreement_warmup.json``; offline validation figures: no checkpoint
    between evaluations).  The reference names no warm-up's figures too."""
    def describe(family: Row) -> Row:
        none = family["means"]["none"]
        return {"default": "agreement_warmup: 100 (label-free checkpoint selection)",
                "tuned_on": "Dial, expert, labels hidden, seeds 0–1",
                "kept_out_of_tuning": family["kept_out_of_tuning"],
                "reference": f"the family's own best warm-up ({_span(family['family_ties'])}) on the "
                             f"same validation episodes; none: {100 * none['offline_f1_1']:.1f} / "
                             f"{100 * none['offline_align']:.1f}"}
    return study_rows(results, WARMUP, ("shipped", "family"), ("offline_f1_1", "offline_align"), describe)


def budget_rows(results: Path) -> list[Row]:
    """The decoder's delay budget against none (``delay_budget.json``; an online detector only)."""
    return study_rows(results, BUDGET, ("shipped", "none"), ("online_f1_1", "online_align"), lambda family: {
        "default": "delay budget: 6 steps (duration decoder)",
        "tuned_on": "Craft full and partial, expert, seeds 0–4",
        "kept_out_of_tuning": family.get("kept_out_of_tuning", "the family"),
        "reference": f"no budget (mean delay {_delay(family['means']['none'])}; "
                     f"{_delay(family['means']['shipped'])} with it)"})


def head_budget_rows(results: Path) -> list[Row]:
    """The same budget for mode 'head_hsmm' (``head_duration.json``), on the families whose runs
    ``ompn_train`` gave that mode, the design runs left out."""
    path = results / HEAD_DURATION
    if not path.is_file():
        return []
    rows = []
    for family in json.loads(path.read_text(encoding="utf-8"))["families"]:
        means = family["means"]
        if family["role"] == "design" or not means["now_head_hsmm_runs"]["runs"]:
            continue
        with_it, none = means["head_hsmm"], means["head_hsmm_any_delay"]
        if none is None:
            continue
        mine, ref = ({"online_f1_1": m["f1_tol1"], "online_align": m["align"]} for m in (with_it, none))
        gap = {k: mine[k] - ref[k] for k in mine}
        seeds = list(family["seeds"])
        rows.append({
            "default": "delay budget: 6 steps (duration decoder over the head, head_hsmm)",
            "tuned_on": "Craft full and partial, expert, seeds 0–4 (with the duration decoder)",
            "kept_out_of_tuning": "the family" if family["role"] == "kept out" else f"seeds {_span(seeds)}",
            "reference": f"no budget (mean delay {_delay(none)}; {_delay(with_it)} with it)",
            "family": family["family"], "seeds": seeds,
            "with_default": {k: mine.get(k) for k in FIGURES}, "without": {k: ref.get(k) for k in FIGURES},
            "gap": gap, "holds": min(gap.values()) >= -TOLERANCE,
        })
    return rows


def _delay(means: Row) -> str:
    """``"8.5 steps, 12 % at the end"`` (the share only where the study recorded it)."""
    share = means.get("at_end_share")
    return f"{means['delay_mean']:.1f} steps" + ("" if share is None else f", {100 * share:.0f} % at the end")


def build(results: Path, command: Sequence[str]) -> Path:
    """Write ``results/transfer.json`` from ``results/own_data.json`` (and ``detector_selection.json``)
    and regenerate the README."""
    rows = json.loads((results / OWN_DATA).read_text(encoding="utf-8"))["rows"]
    found = [row for check in CHECKS if (row := evaluate(check, rows)) is not None]
    found += detector_rows(results)
    found += final_auto_rows(results)
    found += warmup_rows(results)
    found += budget_rows(results)
    found += head_budget_rows(results)
    meta = {
        "command": list(command), "date": time.strftime("%Y-%m-%d", time.gmtime()),
        "tolerance_points": 100 * TOLERANCE,
        "source": f"{OWN_DATA}, {SELECTION}, {FINAL_AUTO}, {WARMUP}, {BUDGET}, {HEAD_DURATION}",
        "held_out": "test episodes of each bag set (20 %), never trained on or tuned on; the human-like "
                    "family was kept out of every tuning",
        "detector": f"the online figures of {OWN_DATA} use the detector rule of their date: the current "
                    "one (one standard error) for the human-like Craft and the expert Craft partial rows, "
                    f"the previous one for the others; {SELECTION} rescores the human-like checkpoints "
                    f"with both, and {FINAL_AUTO} scores both sides of its rows with the current one",
    }
    target = results / TRANSFER
    target.write_text(json.dumps({"meta": meta, "rows": found}, indent=1) + "\n", encoding="utf-8")
    write_readme(results)
    return target


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m lab.transfer [RESULTS_DIR]``: write ``transfer.json`` and the README."""
    args = list(sys.argv[1:] if argv is None else argv)
    results = Path(args[0]) if args else Path("results")
    if not (results / OWN_DATA).is_file():
        print(f"transfer: error: {results / OWN_DATA} does not exist (python -m lab.own_data collate)",
              file=sys.stderr)
        return 2
    print(f"wrote {build(results, ['python', '-m', 'lab.transfer', *args])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
