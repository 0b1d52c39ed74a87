"""The figure of the memory depth × size sweep: held-out alignment accuracy against the slot size
``m``, one line per memory depth ``n`` (error bars: std over seeds), the paper's cells marked
(Lu et al., ICLR 2021, Appendix "Hyperparameter Analysis").  Uses matplotlib's Agg backend."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from lab.report_hparams import HparamsDoc

PAPER_OFFSET = 1.04
PAPER_STEP = 0.03
"""The paper's points of the ``i``-th ``n`` are drawn at ``m · (PAPER_OFFSET + i · PAPER_STEP)`` (log
axis) so that ours and the paper's error bars, and cells of equal value, stay apart."""


def save_hparams_figure(doc: HparamsDoc, path: Path) -> Path:
    """Write the PNG of ``doc`` to ``path`` and return it."""
    cells = list(doc["cells"].values())
    fig, ax = plt.subplots(figsize=(6.0, 4.0))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, n in enumerate(sorted({c["n_slots"] for c in cells})):
        color = colors[i % len(colors)]
        line = sorted((c for c in cells if c["n_slots"] == n), key=lambda c: c["slot_size"])
        ours = [
            (c["slot_size"], c["metrics"]["align_acc"])
            for c in line
            if c["metrics"]["align_acc"]["mean"] is not None
        ]
        if ours:
            ax.errorbar(
                [m for m, _ in ours],
                [100 * float(s["mean"] or 0.0) for _, s in ours],
                yerr=[100 * float(s["std"] or 0.0) for _, s in ours],
                color=color,
                marker="o",
                capsize=3,
                label=f"n={n} (ours)",
            )
        paper = [(c["slot_size"], c["paper_align"]) for c in line if c["paper_align"] is not None]
        if paper:
            ax.errorbar(
                [m * (PAPER_OFFSET + i * PAPER_STEP) for m, _ in paper],
                [100 * p["mean"] for _, p in paper],
                yerr=[100 * p["std"] for _, p in paper],
                color=color,
                marker="D",
                markerfacecolor="none",
                linestyle="none",
                capsize=3,
                label=f"n={n} (paper)",
            )
    sizes = sorted({c["slot_size"] for c in cells})
    ax.set_xscale("log", base=2)
    ax.set_xticks(sizes, [str(m) for m in sizes])
    ax.minorticks_off()
    ax.set_xlabel("slot size m")
    ax.set_ylabel("held-out alignment accuracy (%)")
    ax.set_title(
        "Craft full, no sketch: memory depth n × slot size m\n"
        "bars: std over seeds; paper (Lu et al., ICLR 2021, appendix) drawn just right of its m",
        fontsize=9,
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
