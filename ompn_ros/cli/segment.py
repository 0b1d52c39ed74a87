"""``ompn_segment``: replay bags through the StreamingSegmenter; compare and tune detectors.

Replay (the same class the live node runs)::

    ompn_segment --bag PATH --checkpoint DIR [--reader-config YAML] [--out DIR] [--detector-config YAML]

writes ``pi.npz`` (per episode ``ep<i>_{pi,p_hat,pi_end,expected_position,score}``),
``boundaries.json`` (online events and ground truth), ``metrics.json`` (online vs offline, when the
bag has subtask labels) and ``episode_<i>.png`` plots.

Tuning (choose the per-domain node defaults from measurements)::

    ompn_segment --tune --checkpoint DIR (--bag PATH | --generate N --domain D) \
        [--write-config config/ompn_node_<domain>.yaml]

The tuning objective is the alignment accuracy (strict decoding: steps after the last boundary
belong to the last subtask), then F1 at tolerance 1, then the lower mean detection delay.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from collections.abc import Iterable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from ompn_ros.data.episode import Episode
from ompn_ros.detect import offline
from ompn_ros.detect.online import MODES, BoundaryEvent, DetectorConfig, detect_sequence
from ompn_ros.metrics import alignment_accuracy, mean_f1
from ompn_ros.segmenter import ReplayResult, StreamingSegmenter, replay_episode

MATCH_TOLERANCE = 2
"""A detection within this many steps of a true boundary counts as that boundary (for delays)."""


def replay_all(policy: Any, episodes: Sequence[Episode], config: DetectorConfig) -> list[ReplayResult]:
    """Replay every episode (done step included, as live) through one StreamingSegmenter."""
    segmenter = StreamingSegmenter(policy, config)
    return [replay_episode(segmenter, ep, include_done_step=True) for ep in episodes]


def delay_stats(
    events: Sequence[Sequence[BoundaryEvent] | Sequence[int] | np.ndarray],
    gts: Sequence[np.ndarray],
    detected_at: Sequence[Sequence[int]] | None = None,
) -> dict[str, float]:
    """Detection delay (``detected_at - true boundary``) and false alarms per episode.

    The final boundary (``T - 1``, closed by the episode end) is excluded from both.  A true
    boundary is detected by the first non-final detection within ``MATCH_TOLERANCE`` steps; a
    detection matching no true boundary is a false alarm.
    """
    delays: list[int] = []
    false_alarms = 0
    for i, (evs, gt) in enumerate(zip(events, gts, strict=True)):
        steps = [int(e.step) if isinstance(e, BoundaryEvent) else int(e) for e in evs]  # type: ignore[arg-type]
        when = (
            [int(e.detected_at) for e in evs if isinstance(e, BoundaryEvent)]
            if detected_at is None
            else list(detected_at[i])
        )
        last = int(gt[-1])
        inner = [(s, w) for s, w in zip(steps, when, strict=True) if s != last]
        for g in gt[:-1]:
            hits = [w for s, w in inner if abs(s - int(g)) <= MATCH_TOLERANCE]
            if hits:
                delays.append(min(hits) - int(g))
        false_alarms += sum(1 for s, _ in inner if np.min(np.abs(gt - s)) > 1)
    return {
        "delay_mean": float(np.mean(delays)) if delays else float("nan"),
        "delay_max": float(np.max(delays)) if delays else float("nan"),
        "false_alarms_per_episode": false_alarms / max(1, len(gts)),
    }


def score_predictions(preds: Sequence[np.ndarray], episodes: Sequence[Episode]) -> dict[str, float]:
    """F1 at tolerance 0 and 1 and alignment accuracy (authors' and strict decoding)."""
    gts = [ep.boundaries for ep in episodes]
    labels = [ep.subtask for ep in episodes]
    return {
        "f1_tol0": mean_f1(preds, gts, 0).f1,
        "f1_tol1": mean_f1(preds, gts, 1).f1,
        "align": alignment_accuracy(preds, labels, "authors"),  # type: ignore[arg-type]
        "align_strict": alignment_accuracy(preds, labels, "strict"),  # type: ignore[arg-type]
    }


def compare_detectors(
    policy: Any,
    episodes: Sequence[Episode],
    online_configs: dict[str, DetectorConfig] | None = None,
    *,
    offline_thresholds: Iterable[float] = (0.5,),
    replays: Sequence[ReplayResult] | None = None,
) -> dict[str, dict[str, float]]:
    """Online vs offline detectors on the same episodes (with subtask labels).

    Online detectors see the per-step scores causally (their delay is ``detected_at - boundary``);
    offline detectors (Top-K and thresholding with K = the true number of boundaries, paper
    Algorithms 1-2) need the whole episode, so their delay is measured to the episode end
    (``T - 1 - boundary``).  Returns ``{detector name: {metric: value}}``.
    """
    if not episodes or any(ep.subtask is None for ep in episodes):
        raise ValueError("compare_detectors needs episodes with subtask labels")
    online_configs = online_configs or {"online": DetectorConfig()}
    if replays is None:
        replays = replay_all(policy, episodes, next(iter(online_configs.values())))
    gts = [ep.boundaries for ep in episodes]
    results: dict[str, dict[str, float]] = {}
    for name, cfg in online_configs.items():
        events = [detect_sequence(r.scores, cfg, levels=None) for r in replays]
        preds = [np.array([e.step for e in evs], dtype=np.int64) for evs in events]
        results[name] = {**score_predictions(preds, episodes), **delay_stats(events, gts)}
    offline_preds: dict[str, list[np.ndarray]] = {"offline_topk": [], "offline_auto": []}
    for thr in offline_thresholds:
        offline_preds[f"offline_thr{thr:g}"] = []
    for r, gt in zip(replays, gts, strict=True):
        k = len(gt)
        offline_preds["offline_topk"].append(offline.top_k_boundaries(r.p_hat, k))
        offline_preds["offline_auto"].append(offline.auto_threshold_boundaries(r.p_hat, k)[0])
        for thr in offline_thresholds:
            offline_preds[f"offline_thr{thr:g}"].append(offline.threshold_boundaries(r.p_hat, thr, k))
    for name, preds in offline_preds.items():
        at_end = [[len(r.scores) - 1] * len(p) for r, p in zip(replays, preds, strict=True)]
        results[name] = {**score_predictions(preds, episodes), **delay_stats(preds, gts, at_end)}
    return results


def default_grid() -> list[DetectorConfig]:
    """The detector settings searched by :func:`choose_detector`."""
    highs = [round(float(h), 2) for h in np.arange(0.05, 0.91, 0.05)]
    grid = []
    for high, hyst, min_len, mode in itertools.product(highs, (0.0, 0.1), (1, 3), MODES):
        grid.append(
            DetectorConfig(
                high=high,
                low=max(0.0, round(high - hyst, 2)) if hyst else None,
                min_segment_length=min_len,
                mode=mode,
            )
        )
    return grid


OBJECTIVES = ("f1", "align")
"""What ``--tune`` maximises first: boundary F1 at tolerance 1, or strict alignment accuracy."""
DEFAULT_OBJECTIVE = {"craft": "f1", "dial": "align"}
"""Per domain, the paper's headline metric (Craft: F1 of the boundaries; Dial: alignment)."""


def _objective(metrics: dict[str, float], objective: str = "f1") -> tuple[float, float, float]:
    """Sort key of a detector's metrics: the objective, then the other metric, then a short delay."""
    delay = metrics["delay_mean"]
    first, second = ("f1_tol1", "align_strict") if objective == "f1" else ("align_strict", "f1_tol1")
    return (metrics[first], metrics[second], -(delay if np.isfinite(delay) else 1e9))


def choose_detector(
    policy: Any,
    episodes: Sequence[Episode],
    grid: Sequence[DetectorConfig] | None = None,
    objective: str = "f1",
) -> tuple[DetectorConfig, dict[str, float], dict[str, dict[str, float]]]:
    """Grid-search the online detector on labelled episodes, maximising ``objective`` (``OBJECTIVES``).

    Returns ``(best config, its metrics, comparison with the offline detectors for the best)``.
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"detector tuning objective must be one of {OBJECTIVES}, got {objective!r}")
    grid = list(grid or default_grid())
    replays = replay_all(policy, episodes, grid[0])
    gts = [ep.boundaries for ep in episodes]
    best: tuple[tuple[float, float, float], DetectorConfig, dict[str, float]] | None = None
    for cfg in grid:
        events = [detect_sequence(r.scores, cfg) for r in replays]
        preds = [np.array([e.step for e in evs], dtype=np.int64) for evs in events]
        metrics = {**score_predictions(preds, episodes), **delay_stats(events, gts)}
        key = _objective(metrics, objective)
        if best is None or key > best[0]:
            best = (key, cfg, metrics)
    assert best is not None
    comparison = compare_detectors(policy, episodes, {"online": best[1]}, replays=replays)
    return best[1], best[2], comparison


def write_node_config(
    path: str | Path, domain: str, config: DetectorConfig, measured: dict[str, dict[str, float]], source: str
) -> Path:
    """Write a ``--params-file`` for ompn_node with the chosen detector and the measurements as comments."""
    lines = [
        f"# ompn_node defaults for the {domain} domain, chosen by `ompn_segment --tune` on {source}.",
        "# Measured on the tuning episodes (online = these settings;",
        "# offline = whole-episode detectors with K = the true number of boundaries):",
    ]
    for name, m in measured.items():
        summary = ", ".join(f"{k}={v:.3f}" for k, v in m.items())
        lines.append(f"#   {name}: {summary}")
    lines += [
        "/**/ompn_node:",
        "  ros__parameters:",
        f"    domain: {domain}",
        f"    detector_high: {config.high}",
        f"    detector_hysteresis: {round(config.high - config.low_threshold, 4)}",
        f"    detector_min_segment_length: {config.min_segment_length}",
        f"    detector_mode: {config.mode}",
        f"    detector_force_first_step_low: {str(config.force_first_step_low).lower()}",
        "",
    ]
    out = Path(path)
    out.write_text("\n".join(lines), encoding="utf-8")
    return out


def load_detector_yaml(path: str | Path) -> DetectorConfig:
    """Detector settings from an ompn_node params file (``detector_*`` keys) or a plain mapping."""
    import yaml

    data = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
    for _ in range(3):  # unwrap '/**' / node name / 'ros__parameters'
        if isinstance(data, dict) and len(data) == 1 and not any(k.startswith("detector") for k in data):
            data = next(iter(data.values()))
    params = {k[len("detector_") :]: v for k, v in data.items() if k.startswith("detector_")}
    if "hysteresis" in params:
        hysteresis = float(params.pop("hysteresis"))
        if hysteresis > 0:
            params["low"] = max(0.0, round(float(params.get("high", 0.5)) - hysteresis, 6))
    return DetectorConfig.from_dict(params)


def _load_episodes(args: argparse.Namespace) -> list[Episode]:
    if args.bag:
        from ompn_ros.data.bag_reader import ReaderSpec, read_episodes

        spec = (
            ReaderSpec.from_yaml(args.reader_config)
            if args.reader_config
            else (ReaderSpec.for_domain(args.domain) if args.domain else None)
        )
        return list(read_episodes(args.bag, spec=spec).episodes)
    if args.generate:
        if args.domain == "craft":
            from sim_nodes.craft import PAPER_TASKS, generate_episode

            tasks = list(PAPER_TASKS)  # makebed, makeaxe, makeshears in turn, as in the training data
            return [generate_episode(args.seed + i, task=tasks[i % len(tasks)]) for i in range(args.generate)]
        if args.domain == "dial":
            from sim_nodes.dial import generate_episode as generate_dial

            return [generate_dial(args.seed + i) for i in range(args.generate)]
        raise SystemExit("--generate needs --domain craft|dial")
    raise SystemExit("give --bag PATH or --generate N --domain D")


def _json_safe(value: Any) -> Any:
    """NaN/inf -> None (strict JSON), recursively."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def run_replay(
    policy: Any, episodes: Sequence[Episode], config: DetectorConfig, out: Path, plot_episodes: int = 3
) -> dict[str, Any]:
    """Replay ``episodes`` and write the output files into ``out``; returns the summary."""
    from ompn_ros.plotting import plot_episode

    out.mkdir(parents=True, exist_ok=True)
    replays = replay_all(policy, episodes, config)
    arrays: dict[str, np.ndarray] = {}
    doc: list[dict[str, Any]] = []
    for i, (ep, r) in enumerate(zip(episodes, replays, strict=True)):
        for key in ("pi", "p_hat", "pi_end", "expected_position", "scores"):
            arrays[f"ep{i}_{key.rstrip('s') if key == 'scores' else key}"] = getattr(r, key)
        gt = ep.boundaries.tolist() if ep.subtask is not None else None
        doc.append(
            {
                "episode": i,
                "task": ep.task,
                "seed": ep.seed,
                "steps": ep.length,
                "boundaries": [asdict(b) for b in r.boundaries],
                "true_boundaries": gt,
            }
        )
        if i < plot_episodes:
            auto = offline.auto_threshold_boundaries(r.p_hat, len(gt))[0].tolist() if gt else None
            plot_episode(
                out / f"episode_{i}.png",
                r.pi,
                r.pi_end,
                r.scores,
                true_boundaries=gt,
                detected_boundaries=[b.step for b in r.boundaries],
                offline_boundaries=auto,
                high=config.high,
                low=config.low_threshold,
                title=f"{ep.task} seed {ep.seed}: online detector {config.mode}",
            )
    np.savez_compressed(out / "pi.npz", **arrays)  # type: ignore[arg-type]
    (out / "boundaries.json").write_text(
        json.dumps({"detector": config.to_dict(), "episodes": doc}, indent=1)
    )
    summary: dict[str, Any] = {"episodes": len(episodes), "detector": config.to_dict()}
    if episodes and all(ep.subtask is not None for ep in episodes):
        summary["metrics"] = compare_detectors(policy, episodes, {"online": config}, replays=replays)
        (out / "metrics.json").write_text(json.dumps(_json_safe(summary["metrics"]), indent=1))
    return summary


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ompn_segment", description=__doc__.split("\n")[0])
    p.add_argument("--bag", help="bag file/directory/glob to replay")
    p.add_argument("--checkpoint", required=True,
                   help="checkpoint directory (safetensors + JSON), or an ensemble directory (ensemble.json)")
    p.add_argument("--reader-config", help="bag reader spec YAML (config/reader_*.yaml)")
    p.add_argument(
        "--domain", choices=("craft", "dial"), help="reader preset / episode generator / config name"
    )
    p.add_argument("--detector-config", help="YAML with detector_* keys (e.g. config/ompn_node_craft.yaml)")
    p.add_argument("--out", default="segment_out", help="output directory (replay mode)")
    p.add_argument("--plot-episodes", type=int, default=3, help="number of episodes to plot")
    p.add_argument("--tune", action="store_true", help="grid-search the online detector instead of replaying")
    p.add_argument(
        "--generate", type=int, default=0, help="tune/replay on N freshly generated expert episodes"
    )
    p.add_argument("--seed", type=int, default=10_000, help="first seed of --generate")
    p.add_argument(
        "--write-config", help="with --tune: write the chosen settings as an ompn_node params file"
    )
    p.add_argument(
        "--objective", choices=OBJECTIVES, default=None,
        help="with --tune: maximise boundary F1 (tol 1) or alignment first "
        f"(default per domain: {DEFAULT_OBJECTIVE}; f1 without --domain)",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import torch

    from ompn_ros.model.checkpoint import CheckpointError
    from ompn_ros.model.factory import stepper_from_checkpoint

    torch.set_num_threads(1)
    try:
        policy = stepper_from_checkpoint(args.checkpoint)
    except CheckpointError as exc:
        print(f"ompn_segment: error: --checkpoint: {exc}", file=sys.stderr)
        return 2
    episodes = _load_episodes(args)
    if not episodes:
        print("no episodes found", file=sys.stderr)
        return 1
    if args.tune:
        objective = args.objective or DEFAULT_OBJECTIVE.get(args.domain or "", "f1")
        best, metrics, comparison = choose_detector(policy, episodes, objective=objective)
        print(
            json.dumps(
                _json_safe({"best": best.to_dict(), "metrics": metrics, "comparison": comparison}), indent=1
            )
        )
        if args.write_config:
            source = args.bag or f"{args.generate} generated {args.domain} episodes (seeds from {args.seed})"
            write_node_config(
                args.write_config,
                args.domain or "",
                best,
                comparison,
                f"{source}, checkpoint {args.checkpoint}, objective {objective}",
            )
        return 0
    config = load_detector_yaml(args.detector_config) if args.detector_config else DetectorConfig()
    summary = run_replay(policy, episodes, config, Path(args.out), args.plot_episodes)
    print(json.dumps(_json_safe(summary), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
