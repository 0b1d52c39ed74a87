"""A causal boundary head: a small network that reads the last steps of the model's outputs and says,
a fixed number of steps later, whether a subtask ended (docs/experiments.md §51).

For each run of :mod:`lab.own_data`, the trained OMPN's per-step outputs (``p_hat`` and the action
output, teacher-forced: the same as the node's stream) are computed once on the run's training,
validation and held-out test episodes (cached in ``<work>/head/<arm>.npz``).  The head, an MLP over a
window of ``WINDOW`` steps, is trained on the training episodes to give, for each lag ``j`` in
``0..MAX_LAG``, the probability that step ``t - j`` is a boundary.  Its targets are either the true
boundaries (``labels``) or the model's own offline Top-K segmentation of the training episodes
(``topk``, the paper's detector with the episode's number of subtasks).  The node would publish the
boundary of step ``t - d`` at step ``t`` when the head's probability passes ``theta`` (at least
``gap`` steps after the previous one; with ``peak`` only when lag ``d`` is likelier than lag
``d - 1``); at the episode end the smaller lags close the last ``d`` steps.  ``d``, ``theta``,
``gap`` and ``peak`` are chosen on the run's validation episodes for alignment.  Nothing of the
OMPN is retrained.  ``--head gru`` swaps the window MLP for a GRU over the whole episode so far.

The window head is trained by the product's :func:`ompn_ros.train.boundary_head.train_head` (what
``ompn_train`` runs, docs/design.md#boundary-head).  The decoding here is the study's own: it
publishes step ``t - d`` at step ``t`` and picks the rule by strict alignment; the node's decoder
(:mod:`ompn_ros.detect.head`) places the same boundaries for a rule, one step later (it holds the newest step,
so an episode's 'done' observation never places one) and ``ompn_train`` picks by the authors'
alignment (docs/experiments.md §52).

    python -m lab.boundary_head --work runs/own_data --robot runs/own_robot   # results/boundary_head.json
    python -m lab.boundary_head --work runs/own_data ARM [ARM ...]            # printed only
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lab.detector_selection import _bounds, arm_splits, bundled_of, cached_scores, decoded, online_figures
from lab.own_data import arm_by_name
from lab.report import write_study
from lab.scoring import offline_boundaries
from ompn_ros.app import training
from ompn_ros.app.training import apply_overrides, load_config
from ompn_ros.detect.defaults import DURATION_DELAY, DURATION_LAG
from ompn_ros.detect.duration_tuning import calibrate_duration
from ompn_ros.detect.grid import scores_from_p_hats
from ompn_ros.detect.head import BoundaryHead
from ompn_ros.detect.head import windowed as windowed_rows
from ompn_ros.detect.offline import top_k_boundaries
from ompn_ros.detect.settings import DetectorSettings, load_detector_settings
from ompn_ros.metrics import alignment_accuracy, mean_f1
from ompn_ros.model.checkpoint import load_checkpoint
from ompn_ros.train.batching import collate
from ompn_ros.train.boundary_head import EPOCHS, HIDDEN, MAX_HEAD_LAG, WINDOW
from ompn_ros.train.boundary_head import targets as lag_targets
from ompn_ros.train.boundary_head import train_head as train_window_head
from ompn_ros.train.trainer import train_val_episodes

MAX_LAG = MAX_HEAD_LAG
SPLITS = ("train", "val", "test")


def _outputs(policy: Any, episodes: Sequence[Any]) -> list[np.ndarray]:
    """Per episode ``[T, n+1+A]``: ``p_hat`` beside the action output (a softmax when discrete)."""
    cfg = policy.config
    out_rows: list[np.ndarray] = []
    policy.eval()
    with torch.no_grad():
        for start in range(0, len(episodes), 64):
            chunk = list(episodes[start:start + 64])
            batch = collate(chunk, cfg.action_type, cfg.action_dim, cfg.sketch_mode != "none")
            out = policy.forward_sequence(batch.obs, batch.mask, batch.sketch)
            act = out.action_out.softmax(-1) if cfg.action_type == "discrete" else out.action_out
            feats = torch.cat([out.p_hat, act], dim=-1).numpy()
            out_rows += [feats[i, :ep.length].astype(np.float32) for i, ep in enumerate(chunk)]
    return out_rows


def cached_outputs(arm_name: str, work: Path) -> dict[str, list[np.ndarray]]:
    """``<split>_x`` (outputs) and ``<split>_l`` (labels) per split, from ``<work>/head/<arm>.npz``."""
    target = work / "head" / f"{arm_name}.npz"
    if not target.is_file():
        train, val, test, policy = arm_splits(arm_name, work)
        _save(target, policy, (train, val, test))
    return _load(target)


def _save(target: Path, policy: Any, splits: tuple[Sequence[Any], ...]) -> None:
    doc: dict[str, np.ndarray] = {}
    for split, eps in zip(SPLITS, splits, strict=True):
        for i, (x, ep) in enumerate(zip(_outputs(policy, eps), eps, strict=True)):
            doc[f"{split}_x{i}"], doc[f"{split}_l{i}"] = x, np.asarray(ep.subtask, dtype=np.int64)
    target.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(target, **doc)  # type: ignore[arg-type]


ROBOT_READER = Path(__file__).resolve().parents[1] / "config" / "reader_dial_robot.yaml"


def robot_splits(flow: Path) -> tuple[list[Any], list[Any], list[Any], Any]:
    """(train, validation, test) episodes of the robot profile's run of ``examples/own_robot.py --out
    FLOW`` (``FLOW/bags/train`` split as ``ompn_train`` split it, ``FLOW/bags/heldout`` as test) and
    its best checkpoint's policy."""
    config = load_config(str(ROBOT_READER.parent / "train_dial.yaml"))
    apply_overrides(config, ["data.domain=null", f"data.reader_spec={ROBOT_READER}"])
    data = training.bag_data([str(flow / "bags" / "train")], config["data"])
    _, cfg = training.build_configs(config, data, flow / "model", True, True)
    train, val, _ = train_val_episodes(data.episodes, cfg)
    test = training.bag_data([str(flow / "bags" / "heldout")], config["data"]).episodes
    return list(train), list(val), list(test), load_checkpoint(flow / "model" / "best")[0]


def robot_outputs(flow: Path) -> dict[str, list[np.ndarray]]:
    """The robot profile's outputs on :func:`robot_splits`, cached in ``FLOW/head.npz``."""
    target = flow / "head.npz"
    if not target.is_file():
        train, val, test, policy = robot_splits(flow)
        _save(target, policy, (train, val, test))
    return _load(target)


def _load(target: Path) -> dict[str, list[np.ndarray]]:
    with np.load(target) as doc:
        got: dict[str, list[np.ndarray]] = {}
        for split, kind in itertools.product(SPLITS, "xl"):
            n = sum(1 for k in doc.files if k.startswith(f"{split}_x"))
            got[f"{split}_{kind}"] = [doc[f"{split}_{kind}{i}"] for i in range(n)]
    return got


def windowed(x: np.ndarray) -> np.ndarray:
    """``[T, WINDOW * F]``: :func:`ompn_ros.detect.head.windowed` at the head's window."""
    return windowed_rows(x, WINDOW)


def targets(bounds: np.ndarray, length: int) -> np.ndarray:
    """``[T, MAX_LAG + 1]``: :func:`ompn_ros.train.boundary_head.targets`."""
    return lag_targets(bounds, length, MAX_LAG)


def topk_bounds(x: np.ndarray, labels: np.ndarray, n_p: int) -> np.ndarray:
    """The model's own offline Top-K segmentation, with the episode's number of subtasks."""
    chosen = top_k_boundaries(x[:, :n_p].astype(np.float64), len(_bounds([labels])[0]))
    return np.append(chosen[chosen < len(labels) - 1], len(labels) - 1)


class _GRU(torch.nn.Module):
    def __init__(self, n_in: int) -> None:
        super().__init__()
        self.gru = torch.nn.GRU(n_in, HIDDEN, batch_first=True)
        self.out = torch.nn.Sequential(torch.nn.Linear(HIDDEN + n_in, HIDDEN), torch.nn.ReLU(),
                                       torch.nn.Linear(HIDDEN, MAX_LAG + 1))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.out(torch.cat([self.gru(z)[0], z], dim=-1))


@dataclass(frozen=True)
class Head:
    """A trained head: ``head(x)`` maps one episode's outputs ``[T, F]`` to ``[T, MAX_LAG + 1]``
    probabilities, computed causally (row ``t`` reads rows ``<= t`` only): the product's window head
    (:class:`~ompn_ros.detect.head.BoundaryHead`), or the lab's GRU."""

    window: BoundaryHead | None = None
    net: torch.nn.Module | None = None
    mean: np.ndarray | None = None
    std: np.ndarray | None = None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if self.window is not None:
            return self.window.probabilities(x)
        assert self.net is not None and self.mean is not None and self.std is not None
        z = torch.from_numpy(((x - self.mean) / self.std).astype(np.float32))
        with torch.no_grad():
            return torch.sigmoid(self.net(z[None])[0]).numpy()


def _padded(arrays: Sequence[np.ndarray]) -> tuple[torch.Tensor, torch.Tensor]:
    out = np.zeros((len(arrays), max(len(a) for a in arrays), arrays[0].shape[1]), dtype=np.float32)
    mask = np.zeros(out.shape[:2], dtype=np.float32)
    for i, a in enumerate(arrays):
        out[i, :len(a)], mask[i, :len(a)] = a, 1.0
    return torch.from_numpy(out), torch.from_numpy(mask)


def train_head(xs: Sequence[np.ndarray], bounds: Sequence[np.ndarray], seed: int, recurrent: bool) -> Head:
    """The head on every step of the training episodes, binary cross-entropy per lag: the product's
    window head (:func:`ompn_ros.train.boundary_head.train_head`), or a GRU over the episode so far."""
    if not recurrent:
        return Head(window=train_window_head(xs, bounds, seed))
    torch.manual_seed(seed)
    cat = np.concatenate(xs)
    mean, std = cat.mean(0), cat.std(0) + 1e-6
    net = _GRU(cat.shape[1])
    z, mask = _padded([((x - mean) / std).astype(np.float32) for x in xs])
    y, _ = _padded([targets(b, len(x)) for x, b in zip(xs, bounds, strict=True)])
    opt = torch.optim.Adam(net.parameters(), lr=2e-3, weight_decay=1e-4)
    gen = torch.Generator().manual_seed(seed)
    for _ in range(EPOCHS):
        for idx in torch.randperm(len(xs), generator=gen).split(16):
            raw = torch.nn.functional.binary_cross_entropy_with_logits(net(z[idx]), y[idx], reduction="none")
            loss = (raw.mean(-1) * mask[idx]).sum() / mask[idx].sum()
            opt.zero_grad()
            loss.backward()
            opt.step()
    net.eval()
    return Head(net=net, mean=mean, std=std)


@dataclass(frozen=True)
class Rule:
    """How the head's probabilities become published boundaries (see :func:`decode`)."""

    lag: int
    theta: float
    gap: int
    peak: bool


def _fires(q: np.ndarray, t: int, j: int, rule: Rule) -> bool:
    if q[t, j] < rule.theta:
        return False
    return not (rule.peak and j > 0 and q[t, j - 1] > q[t, j])


def decode(q: np.ndarray, rule: Rule) -> tuple[list[int], list[int]]:
    """(boundary steps, steps they are published at) of one episode; the last step closes it."""
    length = len(q)
    steps: list[int] = []
    when: list[int] = []
    last = -(10**9)
    for t in range(length):
        s = t - rule.lag
        if 1 <= s < length - 1 and s - last >= rule.gap and _fires(q, t, rule.lag, rule):
            steps.append(s)
            when.append(t)
            last = s
    for s in range(max(1, length - rule.lag), length - 1):
        if s - last >= rule.gap and _fires(q, length - 1, length - 1 - s, rule):
            steps.append(s)
            when.append(length - 1)
            last = s
    return [*steps, length - 1], [*when, length - 1]


def score(qs: Sequence[np.ndarray], labels: Sequence[np.ndarray], rule: Rule) -> dict[str, float]:
    """The head's probabilities ``qs`` decoded by ``rule``: :func:`~lab.detector_selection.online_figures`."""
    decoded_eps = [decode(q, rule) for q in qs]
    return online_figures([np.array(s, dtype=np.int64) for s, _ in decoded_eps], [w for _, w in decoded_eps],
                          labels)


THETAS = tuple(round(0.05 * i, 2) for i in range(1, 20))
RULES = [Rule(d, th, g, p) for d in range(1, MAX_LAG + 1) for th in THETAS for g in (1, 2, 3, 4, 6, 8)
         for p in (False, True)]
"""The rule grid: lag 1..MAX_LAG (the delay budget), theta 0.05..0.95, gap, peak."""


def pick(qs: Sequence[np.ndarray], labels: Sequence[np.ndarray]) -> tuple[Rule, dict[str, float]]:
    """The rule with the best validation alignment, then F1@1, then the smaller lag; and its figures."""
    scored = [(score(qs, labels, r), r) for r in RULES]
    best = max(scored, key=lambda sr: (round(sr[0]["online_align"], 6), round(sr[0]["online_f1_1"], 6),
                                       -sr[1].lag))
    return best[1], best[0]


def offline(xs: Sequence[np.ndarray], labels: Sequence[np.ndarray], n_p: int, domain: str
            ) -> dict[str, float]:
    """The paper's offline detector of the domain (:func:`lab.scoring.offline_boundaries`) on test."""
    bounds = _bounds(list(labels))
    preds = [offline_boundaries(domain, x[:, :n_p].astype(np.float64), len(b))
             for x, b in zip(xs, bounds, strict=True)]
    return {"f1_1": mean_f1(preds, bounds, 1).f1,
            "align": alignment_accuracy(preds, list(labels), "authors"),
            "align_strict": alignment_accuracy(preds, list(labels), "strict")}


def heads(data: dict[str, list[np.ndarray]], n_p: int, recurrent: bool, seed: int) -> dict[str, Any]:
    """Per target (``labels``, ``topk``): the rule validation picked and its test figures."""
    row: dict[str, Any] = {}
    for target in ("labels", "topk"):
        bounds = (_bounds(data["train_l"]) if target == "labels" else
                  [topk_bounds(x, lab, n_p) for x, lab in zip(data["train_x"], data["train_l"], strict=True)])
        head = train_head(data["train_x"], bounds, seed, recurrent)
        rule, val = pick([head(x) for x in data["val_x"]], data["val_l"])
        row[f"head_{target}"] = {"rule": asdict(rule), "val": val,
                                 **score([head(x) for x in data["test_x"]], data["test_l"], rule)}
    return row


def study_arm(arm_name: str, work: Path, recurrent: bool = False, seed: int = 0) -> dict[str, Any]:
    """One run of :mod:`lab.own_data` (row cached in ``<work>/head/<arm>.json``): offline, the bundled
    detector, the duration decoder tuned within the budget, the heads."""
    cached = work / "head" / f"{arm_name}{'_gru' if recurrent else ''}{f'_seed{seed}' if seed else ''}.json"
    if cached.is_file():
        return dict(json.loads(cached.read_text(encoding="utf-8")))
    data = cached_outputs(arm_name, work)
    scores = cached_scores(arm_name, work)
    n_p = scores["val_p"][0].shape[1]
    settings = load_detector_settings(work / "runs" / arm_name / "best")
    row: dict[str, Any] = {"arm": arm_name, "offline": offline(data["test_x"], data["test_l"], n_p,
                                                               arm_by_name(arm_name).domain),
                           "bundled": _bundled(settings, scores)}
    if arm_by_name(arm_name).domain == "craft":
        cal = calibrate_duration(scores_from_p_hats(scores["val_p"]), _bounds(scores["val_l"]), DURATION_LAG,
                                 "align", max_delay=DURATION_DELAY)
        row["decoder_budget"] = decoded(cal.config, cal.model, scores["test_p"], scores["test_l"])
    row.update(heads(data, n_p, recurrent, seed))
    cached.write_text(json.dumps(row, indent=1) + "\n", encoding="utf-8")
    return row


def study_robot(flow: Path, recurrent: bool = False, seed: int = 0) -> dict[str, Any]:
    """The robot profile: offline, the detector the checkpoint bundles, the heads."""
    data = robot_outputs(flow)
    n_p = int(load_checkpoint(flow / "model" / "best")[0].config.n_slots) + 1
    scores = {f"{split}_{kind}": [x[:, :n_p].astype(np.float64) for x in data[f"{split}_x"]] if kind == "p"
              else data[f"{split}_l"] for split in ("val", "test") for kind in "pl"}
    return {"arm": "robot_profile", "offline": offline(data["test_x"], data["test_l"], n_p, "dial"),
            "bundled": _bundled(load_detector_settings(flow / "model" / "best"), scores),
            **heads(data, n_p, recurrent, seed)}


def _bundled(settings: DetectorSettings, scores: dict[str, list[np.ndarray]]) -> dict[str, Any]:
    """The detector a run bundles, on test, with its validation figures (for :func:`chosen`)."""
    return {**bundled_of(settings, scores),
            "val": decoded(settings.online, settings.duration_model, scores["val_p"], scores["val_l"])}


def _arms(prefix: str, seeds: Sequence[int]) -> tuple[str, ...]:
    return tuple(f"{prefix}_seed{s}" if s or "dial" not in prefix else prefix for s in seeds)


_PARTIAL, _DIAL = "final_craft_partial_complete", "final_dial_complete"
FAMILIES = (
    ("Craft partial, expert, seeds 10–11", "design", _arms(_PARTIAL, (10, 11))),
    ("Dial, expert, seed 0", "design", _arms(_DIAL, (0,))),
    ("Craft partial, expert, seeds 12–14", "held-out seeds", _arms(_PARTIAL, (12, 13, 14))),
    ("Craft partial, human-like, seeds 10–14", "held-out family",
     _arms("human_craft_partial_complete", range(10, 15))),
    ("Craft full, human-like, seeds 10–14", "held-out family",
     _arms("human_craft_full_complete", range(10, 15))),
    ("Dial, expert, seeds 1–4", "held-out seeds", _arms(_DIAL, (1, 2, 3, 4))),
    ("Dial, human-like, seeds 5–9", "held-out family", _arms("human_dial_complete", range(5, 10))),
)
"""(family, role, runs): the head's window, size, targets and rule grid were set on the design rows."""
ROBOT_FAMILY = ("Dial robot profile (proprioception only), 50 held-out episodes", "held-out family")
FIGURES = ("online_f1_1", "online_align", "delay_mean", "at_end_share")
RESULTS = "boundary_head.json"


def _mean(rows: Sequence[dict[str, Any]], key: str, fields: Sequence[str]) -> dict[str, float] | None:
    if not all(key in r for r in rows):
        return None
    return {f: float(np.mean([r[key][f] for r in rows])) for f in fields}


def chosen(row: dict[str, Any]) -> dict[str, Any]:
    """What a choice on the run's validation episodes would run: the head trained on labels when its
    validation alignment beats the bundled detector's, else the bundled detector (test figures)."""
    head, ref = row["head_labels"], row["bundled"]
    if head["val"]["online_align"] > ref["val"]["online_align"]:
        return {"detector": "head", "f1_1": head["online_f1_1"], "align": head["online_align"]}
    return {"detector": "bundled", "f1_1": ref["f1_1"], "align": ref["align"]}


def family_row(family: str, role: str, rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Means over the family's runs, and the runs."""
    choices = [chosen(r) for r in rows] if all("val" in r["bundled"] for r in rows) else None
    means = {"chosen": None if choices is None else {
                 "f1_1": float(np.mean([c["f1_1"] for c in choices])),
                 "align": float(np.mean([c["align"] for c in choices])),
                 "head_runs": sum(c["detector"] == "head" for c in choices)},
             "offline": _mean(rows, "offline", ("f1_1", "align")),
             "bundled": _mean(rows, "bundled", ("f1_1", "align", "delay")),
             "decoder_budget": _mean(rows, "decoder_budget", FIGURES),
             **{k: _mean(rows, k, FIGURES) for k in ("head_labels", "head_topk")}}
    return {"family": family, "role": role, "runs": len(rows), "means": means, "rows": list(rows)}


META = {"held_out": "test episodes of each run's bags (20 %; the robot profile: 50 episodes of other "
                    "seeds), never trained or tuned on; each rule chosen on the run's validation episodes",
        "window": WINDOW, "max_lag": MAX_LAG, "hidden": HIDDEN, "epochs": EPOCHS}


def main(argv: list[str] | None = None) -> int:
    """``python -m lab.boundary_head [--work W] [--robot FLOW] [--results R]``: ``R/boundary_head.json``;
    with ARMs, their rows are printed only."""
    parser = argparse.ArgumentParser(prog="python -m lab.boundary_head", description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, default=Path("runs/own_data"))
    parser.add_argument("--robot", type=Path, help="an `examples/own_robot.py --out` directory")
    parser.add_argument("--results", type=Path, default=Path("results"))
    parser.add_argument("--head", choices=("window", "gru"), default="window")
    parser.add_argument("--seed", type=int, default=0, help="the head's initialisation and batch order")
    parser.add_argument("arms", nargs="*")
    given = list(argv if argv is not None else sys.argv[1:])
    args = parser.parse_args(given)
    torch.set_num_threads(1)
    recurrent = args.head == "gru"
    if args.arms:
        for arm in args.arms:
            print(json.dumps(study_arm(arm, args.work, recurrent, args.seed)), flush=True)
        return 0
    families = [family_row(f, role, [study_arm(a, args.work, recurrent, args.seed) for a in arms])
                for f, role, arms in FAMILIES]
    if args.robot:
        families.append(family_row(*ROBOT_FAMILY, [study_robot(args.robot, recurrent, args.seed)]))
    command = ["python", "-m", "lab.boundary_head", *given]
    print(f"wrote {write_study(args.results, RESULTS, command, {**META, 'head_seed': args.seed}, families)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
