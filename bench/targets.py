"""The project's performance targets, each tied to one figure of ``bench/latest.json``.

``bench/report.py`` turns them into the table at the top of BENCHMARKS.md (figure, target, today's
value, met or not, the machine that measured it); ``test/house/test_benchmarks_table.py`` checks that every
key exists in ``latest.json`` with the same unit.  A target belongs here only when the project states
it (BENCHMARKS.md, README, ``docs/goals.md``, a benchmark's own docstring) and ``latest.json`` holds
its figure.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

MACHINE_KEY = "_machine"
"""The reserved key of ``latest.json``: a list of the machines that measured its figures (one entry
per run, each naming its ``areas``), not a figure; every reader of the figures skips it."""


@dataclass(frozen=True)
class Target:
    key: str
    """The figure in ``latest.json``."""
    measures: str
    """What the figure measures, for a reader of BENCHMARKS.md."""
    direction: Literal["<=", ">="]
    bound: float
    unit: str
    """The figure's unit, exactly as ``latest.json`` records it."""
    source: str
    """Where the project states the target."""

    def met(self, value: float) -> bool:
        return value <= self.bound if self.direction == "<=" else value >= self.bound


GOALS = "docs/goals.md"
NODE = "BENCHMARKS.md, the node tables"
RECORDER = "bench/bench_recorder.py"
KEPT = "% of sent before signal"
TARGETS: tuple[Target, ...] = (
    Target("node.craft_segmenter_step_p50", "Craft segmenter step p50 (in process)", "<=", 200, "us", GOALS),
    Target("node.craft_segmenter_step_p99", "Craft segmenter step p99 (in process)", "<=", 1000, "us", NODE),
    Target("node.dial_segmenter_step_p50", "Dial segmenter step p50 (in process)", "<=", 200, "us", GOALS),
    Target("node.dial_segmenter_step_p99", "Dial segmenter step p99 (in process)", "<=", 1000, "us", NODE),
    Target("node.dial_multi_node_step_p50", "several topics: node step p50 (assemble + segment)",
           "<=", 200, "us", NODE),
    Target("node.craft_events_boundary_latency_100hz_p50",
           "Craft observation → `~/boundary` p50, DDS, 100 Hz", "<=", 1.5, "ms", GOALS),
    Target("node.craft_events_boundary_latency_100hz_p99",
           "Craft observation → `~/boundary` p99, DDS, 100 Hz", "<=", 10, "ms", NODE),
    Target("node.dial_events_boundary_latency_100hz_p50",
           "Dial observation → `~/boundary` p50, DDS, 100 Hz", "<=", 1.5, "ms", GOALS),
    Target("node.dial_events_boundary_latency_100hz_p99",
           "Dial observation → `~/boundary` p99, DDS, 100 Hz", "<=", 10, "ms", NODE),
    Target("node.dial_events_1khz_lost_steps", "Dial at 1 kHz for 60 s: steps lost", "<=", 0, "steps", NODE),
    Target("recorder.mcap_2000hz_sigint.kept", "recorder, mcap 2 kHz, SIGINT under load: messages kept",
           ">=", 99.9, KEPT, RECORDER),
    Target("recorder.sqlite3_2000hz_sigterm.kept",
           "recorder, sqlite3 2 kHz, SIGTERM under load: messages kept", ">=", 99.9, KEPT, RECORDER),
    Target("recorder.mcap_1khz_3topics_sigterm.kept",
           "recorder, mcap 1 kHz × 3 topics, SIGTERM: messages kept", ">=", 99.9, KEPT, RECORDER),
    Target("recorder.sqlite3_1khz_3topics_sigint.kept",
           "recorder, sqlite3 1 kHz × 3 topics, SIGINT: messages kept", ">=", 99.9, KEPT, RECORDER),
    Target("recorder.sigkill_mcap.lost_window", "recorder, mcap, SIGKILL: stream lost before the kill",
           "<=", 1, "s before SIGKILL", f"{RECORDER}, the 1 s commit period"),
    Target("recorder.sigkill_sqlite3.lost_window", "recorder, sqlite3, SIGKILL: stream lost before the kill",
           "<=", 1, "s before SIGKILL", f"{RECORDER}, the 1 s commit period"),
    Target("assemble.step_loss", "several topics, assembler in a Python subscriber at 1 kHz: steps lost",
           "<=", 0, "fraction (target 0)", "bench/bench_assemble.py"),
    Target("memory.reader_peak_over_bag", "bag reader: peak memory over bag size", "<=", 1.5, "x",
           "BENCHMARKS.md, reader peak RSS"),
    Target("memory.train_mmap_over_memory", "training from the memory-mapped cache against in memory",
           ">=", 0.9, "x", "BENCHMARKS.md, within 10 %"),
    Target("data.mcap_episode_over_raw_time", "episode reader against a raw rosbags read, mcap: time",
           "<=", 3, "x", "bench/bench_data.py"),
    Target("data.sqlite3_episode_over_raw_time", "episode reader against a raw rosbags read, sqlite3: time",
           "<=", 3, "x", "bench/bench_data.py"),
    Target("calibrate.calibrate_label_free_total_s_60ep", "label-free calibration, 60 validation episodes",
           "<=", 60, "s", "bench/bench_calibrate.py"),
    Target("model.train_speedup_vs_authors_measured_3000fps_bf16_2proc_x_1t",
           "training frames/s against the authors' 3 000, bf16, 2 processes × 1 thread", ">=", 3, "x",
           "BENCHMARKS.md, training speed"),
)
