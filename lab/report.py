"""The reproduction's result files: a typed schema, JSON with stable keys, and ``results/README.md``.

Files per domain (``craft``, ``dial``) of the lab's in-process study (``python -m lab.reproduce``):

* ``<domain>_lab.json``: :data:`DomainResults`, ``{setting: {metric: {"mean", "std", "n"}}}`` with
  snake_case metric keys (``align``, ``align_acc``, ``f1_tol1``, ``constrained_align``,
  ``online_align``, ...), metrics as fractions, mean and std over seeds.
* ``<domain>_extras.json``: :class:`ExtrasDoc`, ``{"extras": {table id: {"title", "rows"}}, "meta"}``
  with the table ids of :data:`EXTRA_IDS`.

and, when present, the reproduction through the product, ``<domain>.json``
(:mod:`lab.reproduce_product`, :func:`product_markdown`), ``craft_hparams.json``
(:mod:`lab.report_hparams`) and ``own_data.json`` / ``own_robot.json`` (:mod:`lab.report_own`).

``results/README.md`` is generated from these files only::

    python -m lab.report [RESULTS_DIR]     # or: python -m lab.reproduce --report-only
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypedDict

import numpy as np

from lab.report_final_auto import final_auto_markdown
from lab.report_head import head_duration_markdown, head_markdown
from lab.report_hparams import hparams_markdown
from lab.report_own import own_markdown
from lab.report_selection import selection_markdown
from lab.report_transfer import transfer_markdown

DOMAINS = ("craft", "dial")
EXTRA_IDS = (
    "k_sweep", "threshold_sweep", "ensembles_per_seed", "ensemble_of_seeds", "distilled", "online_lag",
    "ablations",
)
"""Stable ids of the extra tables, in the order they are written."""
README = "README.md"


class Cell(TypedDict):
    """One metric of one setting over seeds (fractions, except counts, steps and seconds)."""

    mean: float
    std: float
    n: int


DomainResults = dict[str, dict[str, Cell]]
"""``<domain>_lab.json``: setting -> metric -> cell."""
MAIN_SUFFIX = "_lab.json"
"""File name of the lab study's main table after the domain (``<domain>.json`` is the product's)."""


class ExtrasTable(TypedDict):
    """One extra table: its title and its rows (row name -> column -> value or cell)."""

    title: str
    rows: dict[str, dict[str, Any]]


class ExtrasDoc(TypedDict):
    """``<domain>_extras.json``: the extra tables by id, and how the results were made (``meta``:
    seeds, stage wall times, total seconds, test episodes, figures, command, and for a
    re-evaluation the ``trained`` run's command and times)."""

    extras: dict[str, ExtrasTable]
    meta: dict[str, Any]


def k_sweep_title(setting: str) -> str:
    return f"K sweep ({setting}, seed 0, tol=1)"


def threshold_sweep_title(setting: str) -> str:
    return f"Threshold sweep ({setting}, seed 0, alignment)"


def ensembles_per_seed_title(seeds: int) -> str:
    return (
        "Ensembles per seed (members share the seed's split and differ in initialisation; "
        f"p_hat averaged; mean (std) over {seeds} seeds)"
    )


def ensemble_of_seeds_title(seeds: int) -> str:
    return (
        f"Ensemble of the {seeds} seeds (p_hat averaged offline; constrained Top-K with the "
        "min_length most seeds chose)"
    )


def distilled_title(seeds: int, weight: float) -> str:
    return (
        "Distilled: one OMPN per seed that also learns the averaged p_hat of the seed's ensemble "
        f"(train.distill_weight {weight:g}; single-model cost; mean (std) over {seeds} seeds)"
    )


def online_lag_title(seeds: int) -> str:
    return (f"Online decoders against the delay ({seeds} seeds, held out, mean (std)): the threshold "
            "detector tuned on validation; the duration decoder ('hsmm', lag 1, docs/experiments.md §38, "
            "§39) fitted on validation, its threshold tuned there within each mean delay (steps); the "
            "offline detectors of the same checkpoints; at_end_share: the inner boundaries published only "
            "at the episode's end (docs/experiments.md §44)")


def ablations_title(setting: str) -> str:
    return f"Ablations ({setting}, seed 0)"


def table(title: str, rows: dict[str, dict[str, Any]]) -> ExtrasTable:
    return {"title": title, "rows": rows}


def write_results(
    results_dir: Path,
    domain: str,
    results: DomainResults,
    extras: dict[str, ExtrasTable],
    meta: dict[str, Any],
) -> None:
    """Write ``<domain>_lab.json``, ``<domain>_extras.json`` and regenerate ``README.md``."""
    unknown = [k for k in extras if k not in EXTRA_IDS]
    if unknown:
        raise ValueError(f"extras: unknown table ids {unknown}; known: {list(EXTRA_IDS)}")
    results_dir.mkdir(parents=True, exist_ok=True)
    (results_dir / f"{domain}{MAIN_SUFFIX}").write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")
    doc: ExtrasDoc = {"extras": extras, "meta": meta}
    (results_dir / f"{domain}_extras.json").write_text(json.dumps(doc, indent=1) + "\n")
    write_readme(results_dir)


def load(results_dir: Path, domain: str) -> tuple[DomainResults, ExtrasDoc] | None:
    """The committed files of ``domain``, or None when the domain has no results yet."""
    main, extras = results_dir / f"{domain}{MAIN_SUFFIX}", results_dir / f"{domain}_extras.json"
    if not main.is_file() or not extras.is_file():
        return None
    return json.loads(main.read_text()), json.loads(extras.read_text())


# --- markdown ------------------------------------------------------------------------------------

PAPER: dict[str, dict[str, tuple[int | None, int | None]]] = {
    "craft": {
        "full_nosketch": (93, 95),
        "partial_nosketch": (84, 89),
        "full_sketch": (97, 98),
        "partial_sketch": (72, 83),
    },
    "dial": {"nosketch": (87, None), "sketch": (82, None)},
}
"""The paper's alignment accuracy / F1 (%), Lu et al., ICLR 2021, Tables 1-2."""
UNSCALED_COLUMNS = {"members": 0, "min_length": 1, "delay_mean": 2}
"""Extras columns that are counts or steps, not fractions (suffix -> decimals shown)."""
INTRO = [
    "Online = the causal detector of `ompn_node`, tuned for each checkpoint on that run's "
    "validation episodes; 'shipped det.' = the package's default detector settings instead.",
    "",
    "'Constrained' = Top-K restricted to subtasks of at least min_length steps that end at the "
    "episode's last step (our detector, min_length tuned on each run's validation episodes); the "
    "other offline columns use the paper's detector.",
    "",
]
HEADER = (
    "| setting | align acc | F1 tol=1 | F1 tol=0 | constrained align | constrained F1 tol=1 | "
    "online F1 tol=1 | online align | online delay (steps) | false alarms / ep | "
    "online F1, shipped det. | paper align / F1 |"
)


def fmt(cell: dict[str, float] | None, scale: float = 100.0, digits: int = 1) -> str:
    """``mean (std)`` scaled (percent by default); a dash for a missing or non-finite cell."""
    if cell is None or not np.isfinite(cell["mean"]):
        return "–"
    return f"{cell['mean'] * scale:.{digits}f} ({cell['std'] * scale:.{digits}f})"


def extras_cell(column: str, value: Any) -> str:
    """An extras-table cell: fractions in %, counts and step delays (``UNSCALED_COLUMNS``) as they are."""
    if value is None:
        return "–"
    suffix = next((k for k in UNSCALED_COLUMNS if column.endswith(k)), None)
    scale, digits = (1.0, UNSCALED_COLUMNS[suffix]) if suffix else (100.0, 1)
    if isinstance(value, dict):
        return fmt(value, scale, digits)
    return f"{scale * value:.{digits}f}"


def _main_row(domain: str, name: str, row: dict[str, Any]) -> str:
    paper = " / ".join("–" if v is None else str(v) for v in PAPER[domain].get(name, (None, None)))
    return (
        f"| {name} | {fmt(row['align_acc'])} | {fmt(row['f1_tol1'])} | {fmt(row['f1_tol0'])} | "
        f"{fmt(row.get('constrained_align'))} | {fmt(row.get('constrained_f1_tol1'))} | "
        f"{fmt(row['online_f1_tol1'])} | {fmt(row['online_align_strict'])} | "
        f"{fmt(row['online_delay_mean'], 1, 2)} | {fmt(row['online_false_alarms_per_episode'], 1, 2)} | "
        f"{fmt(row.get('online_shipped_f1_tol1'))} | [{paper}] |"
    )


def _extras_lines(extras: dict[str, ExtrasTable], head: str) -> list[str]:
    lines: list[str] = []
    for entry in extras.values():
        rows = entry["rows"]
        cols = list(next(iter(rows.values())))
        lines += [
            "",
            f"{head} {entry['title']}",
            "",
            "| | " + " | ".join(cols) + " |",
            "|---|" + "---|" * len(cols),
        ]
        for key, cells in rows.items():
            lines.append(f"| {key} | " + " | ".join(extras_cell(col, c) for col, c in cells.items()) + " |")
    return lines


def _stage_lines(meta: dict[str, Any]) -> list[str]:
    lines: list[str] = []
    trained = meta.get("trained")
    if trained:
        lines += [f"- {k}: {v:.1f}" for k, v in trained.get("stages", {}).items()]
        lines.append(f"- total: {trained.get('total_seconds', float('nan')):.1f}")
        trained_by = [trained.get("command", []), *trained.get("parallel_commands", [])]
        lines += ["", "Trained by: " + "; ".join(f"`{' '.join(c)}`" for c in trained_by if c)]
        lines += _later_lines(trained)
        lines += ["", f"Re-evaluated without training (`{' '.join(meta['command'])}`):", ""]
    lines += [f"- {k}: {v:.1f}" for k, v in meta["stages"].items()]
    lines.append(f"- total: {meta['total_seconds']:.1f}")
    return lines if trained else lines + _later_lines(meta)


def _later_lines(record: dict[str, Any]) -> list[str]:
    later = record.get("later_commands", [])
    if not later:
        return []
    return ["", "Runs added or trained again later, on the same bags and split, by: "
            + "; ".join(f"`{' '.join(c)}`" for c in later)]


def domain_markdown(domain: str, results: DomainResults, doc: ExtrasDoc, level: int = 2) -> str:
    """The tables of one domain: settings, extra tables, wall time per stage."""
    meta = doc["meta"]
    head, sub = "#" * level, "#" * (level + 1)
    seeds = {name: int(row["align_acc"]["n"]) for name, row in results.items()}
    lines = [
        f"{head} {domain}",
        "",
        f"Held-out test episodes: {meta['n_test']} (never trained on); seeds per setting: "
        f"{seeds}; mean (std) over seeds, in %. Paper numbers in brackets.",
        "",
        *INTRO,
        HEADER,
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    lines += [_main_row(domain, name, row) for name, row in results.items()]
    lines += _extras_lines(doc["extras"], sub)
    lines += ["", f"{sub} Wall time per stage (s)", "", *_stage_lines(meta)]
    return "\n".join(lines) + "\n"


PRODUCT_HEADER = (
    "| setting | seeds | align | F1 tol=1 | F1 tol=0 | online align | online F1 tol=1 | "
    "online delay (steps) | false alarms / ep | train s | paper align / F1 |"
)


def _product_row(domain: str, name: str, row: dict[str, Any], seeds: Sequence[int]) -> str:
    paper = " / ".join("–" if v is None else str(v) for v in PAPER[domain].get(name, (None, None)))
    return (
        f"| {name} | {', '.join(map(str, seeds))} | {fmt(row['align'])} | {fmt(row['f1_tol1'])} | "
        f"{fmt(row['f1_tol0'])} | {fmt(row['online_align'])} | {fmt(row['online_f1_tol1'])} | "
        f"{fmt(row['online_delay_mean'], 1, 2)} | {fmt(row['online_false_alarms_per_episode'], 1, 2)} | "
        f"{fmt(row.get('train_seconds'), 1, 0)} | [{paper}] |"
    )


def product_markdown(results_dir: Path) -> list[str]:
    """The reproduction through ``ompn_train`` and its bundled detectors (``<domain>.json`` of
    :mod:`lab.reproduce_product`): one table per domain and the commands it came from."""
    lines: list[str] = []
    for domain in DOMAINS:
        path = results_dir / f"{domain}.json"
        if not path.is_file():
            continue
        doc = json.loads(path.read_text(encoding="utf-8"))
        record = doc["provenance"]
        lines += [
            f"## {domain}: through the product", "",
            f"`{' '.join(record['reproduce'])}` (package {record['version']}): `ompn_train` "
            f"{record['iterations']} updates per run, scored by `ompn_segment` on the held-out bag "
            f"({record['held_out']}); offline = {record['offline_detector']}; online = "
            f"{record['online_detector']}. Mean (std) over the seeds listed, in %.", "",
            PRODUCT_HEADER, "|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        lines += [_product_row(domain, name, row, record["seeds"]) for name, row in doc["settings"].items()]
        lines += ["", *[f"- {step}: `{cmd}`" for step, cmd in record["collect"].items()]]
        for setting, runs in record["runs"].items():
            for seed, run in runs.items():
                lines.append(f"- {setting} seed {seed} (detector `{run['detector_mode']}`): "
                             + "; ".join(f"`{run['commands'][step]}`" for step in ("train", "segment")))
        lines += [f"- note: {record['note']}"] if record.get("note") else []
        lines.append("")
    return lines


def render_readme(results_dir: Path) -> str:
    """``results/README.md`` from the JSON files of every domain in ``results_dir``."""
    parts = [
        "# OMPN reproduction results",
        "",
        "Generated from the JSON files in this directory by `python -m lab.report` "
        "(`python -m lab.reproduce` rewrites it with every run); edit the JSON, not this file.",
        "",
        *product_markdown(results_dir),
        "The lab's in-process study below trains in-process and tunes its own detectors "
        "(`python -m lab.reproduce`); the tables above are what `ompn_train` and `ompn_segment` give.",
        "",
    ]
    for domain in DOMAINS:
        loaded = load(results_dir, domain)
        if loaded is not None:
            parts.append(domain_markdown(domain, *loaded))
    parts += hparams_markdown(results_dir)
    parts += own_markdown(results_dir)
    parts += transfer_markdown(results_dir)
    parts += selection_markdown(results_dir)
    parts += final_auto_markdown(results_dir)
    parts += head_markdown(results_dir)
    parts += head_duration_markdown(results_dir)
    return "\n".join(parts).rstrip("\n") + "\n"


def write_readme(results_dir: Path) -> Path:
    target = results_dir / README
    target.write_text(render_readme(results_dir), encoding="utf-8")
    return target


def study_main(argv: Sequence[str] | None, module: str, doc: str, name: str, meta: dict[str, Any],
               families: Callable[[Path], list[dict[str, Any]]]) -> int:
    """``python -m <module> [--work W] [--results R]``: ``families(W)`` written to ``R/<name>`` by
    :func:`write_study` (``doc``: the module docstring, whose first paragraph is the help)."""
    parser = argparse.ArgumentParser(prog=f"python -m {module}", description=doc.split("\n\n")[0])
    parser.add_argument("--work", type=Path, default=Path("runs/own_data"))
    parser.add_argument("--results", type=Path, default=Path("results"))
    given = list(argv if argv is not None else sys.argv[1:])
    args = parser.parse_args(given)
    command = ["python", "-m", module, *given]
    print(f"wrote {write_study(args.results, name, command, meta, families(args.work))}")
    return 0


def write_study(results_dir: Path, name: str, command: Sequence[str], meta: dict[str, Any],
                families: list[dict[str, Any]]) -> Path:
    """``results_dir/name``: a lab study's ``meta`` (with its command and today's date) and family rows;
    then the README regenerated."""
    head = {"command": list(command), "date": time.strftime("%Y-%m-%d", time.gmtime()), **meta}
    target = results_dir / name
    target.write_text(json.dumps({"meta": head, "families": families}, indent=1) + "\n", encoding="utf-8")
    write_readme(results_dir)
    return target


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m lab.report [RESULTS_DIR]``: regenerate ``RESULTS_DIR/README.md``."""
    args = list(sys.argv[1:] if argv is None else argv)
    results_dir = Path(args[0]) if args else Path("results")
    if not results_dir.is_dir():
        print(f"report: error: results directory {results_dir} does not exist", file=sys.stderr)
        return 2
    print(f"wrote {write_readme(results_dir)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
