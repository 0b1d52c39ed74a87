"""``ompn_segment --bags`` under an unlucky operator: Ctrl-C and SIGTERM, a killed run's workers,
symbolic link loops, bags that vanish, dangle or cannot be read, a full disk under ``--annotate`` and
two runs annotating into one folder at once.  Every wait is bounded; nothing leaves the machine."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import pytest
import yaml
from batch_bags import SPEC, write_lab_bag
from small_disk import small_disk

from ompn_ros.app import annotate as annotate_module
from ompn_ros.app.batch import BatchSettings, run_batch
from ompn_ros.app.batch_bags import list_bags
from ompn_ros.cli.segment import main
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.model.build import build_policy
from ompn_ros.model.checkpoint import save_checkpoint
from ompn_ros.model.config import OMPNConfig

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Three small bags of another lab, its reader spec and an untrained model."""
    root = tmp_path_factory.mktemp("faults")
    for name, seed in (("a", 1), ("b", 2), ("c", 3)):
        write_lab_bag(root / "bags" / name, seed)
    spec = root / "lab_reader.yaml"
    spec.write_text(yaml.safe_dump(SPEC))
    config = OMPNConfig(obs_dim=4, action_type="continuous", action_dim=2, n_slots=3, slot_size=16)
    save_checkpoint(root / "model", build_policy(config))
    return {"root": root, "bags": root / "bags", "spec": spec, "model": root / "model"}


def _args(lab: dict[str, Path], out: Path, *more: str) -> list[str]:
    return ["--checkpoint", str(lab["model"]), "--reader-config", str(lab["spec"]), "--out", str(out), *more]


THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


def _env(single_thread: bool = True) -> dict[str, str]:
    """The children's environment; ``single_thread=False``: none of the thread-count variables, as a
    user's shell has it (library thread pools start: the workers come from a fork server)."""
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    for name in THREAD_VARIABLES:
        env.pop(name, None)
    return {**env, "OMP_NUM_THREADS": "1"} if single_thread else env


def _many(root: Path, count: int, steps: int = 60) -> Path:
    for i in range(count):
        write_lab_bag(root / f"run{i:02d}", 10 + i, episodes=3, steps=steps)
    return root


def _segment(lab: dict[str, Path], bags: Path, out: Path, *more: str, single_thread: bool = True,
             **popen: Any) -> subprocess.Popen[str]:
    command = [sys.executable, "-m", "ompn_ros.cli.segment", "--bags", str(bags), *_args(lab, out), *more]
    return subprocess.Popen(command, env=_env(single_thread), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, **popen)


def _wait_for_records(out: Path, proc: subprocess.Popen[str], count: int = 1, limit: float = 120) -> int:
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline and proc.poll() is None:
        done = len(list((out / "bags").glob("*.json"))) if (out / "bags").is_dir() else 0
        if done >= count:
            return done
        time.sleep(0.02)
    raise AssertionError(f"no {count} record(s) within {limit} s (rc {proc.poll()})")


# --- 4: SIGINT and SIGTERM ------------------------------------------------------------------------
@pytest.mark.parametrize(("jobs", "signum", "group", "single_thread"), [
    (1, signal.SIGINT, False, True), (2, signal.SIGINT, True, True), (1, signal.SIGTERM, False, True),
    (2, signal.SIGTERM, True, False)])
def test_a_stop_signal_ends_after_the_bags_in_progress_with_the_table(
        lab: dict[str, Path], tmp_path: Path, jobs: int, signum: int, group: bool,
        single_thread: bool) -> None:
    """Ctrl-C (to the whole process group, as a terminal sends it) or SIGTERM (to the group, as a
    cluster scheduler sends it) after the first bag: no new bag is started, the table and summary
    of what finished are written, exit 128 + signal."""
    bags, out = _many(tmp_path / "many", 12), tmp_path / "seg"
    proc = _segment(lab, bags, out, "--jobs", str(jobs), start_new_session=group, single_thread=single_thread)
    at_signal = _wait_for_records(out, proc)
    if group:
        os.killpg(proc.pid, signum)
    else:
        proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signum, err[-3000:]
    assert "Traceback" not in err and f"stopped by {signal.Signals(signum).name}" in err
    summary = json.loads((out / "summary.json").read_text())
    records = len(list((out / "bags").glob("*.json")))
    assert at_signal <= summary["segmented"] == records <= at_signal + 2 * jobs < 12
    table = (out / "segments.csv").read_text().splitlines()
    assert len(table) - 1 == summary["segments"] > 0
    assert main(["--bags", str(bags), *_args(lab, out)]) == 0  # the rerun finishes the rest
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["segmented"], summary["skipped"]) == (12, records)


def test_a_second_ctrl_c_stops_at_once_and_keeps_what_finished(lab: dict[str, Path], tmp_path: Path) -> None:
    bags, out = _many(tmp_path / "many", 12, steps=300), tmp_path / "seg"
    proc = _segment(lab, bags, out, "--jobs", "2", start_new_session=True)
    _wait_for_records(out, proc)
    workers = _descendants(proc.pid)
    os.killpg(proc.pid, signal.SIGINT)
    time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "Traceback" not in err, err[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert 1 <= summary["segmented"] == len(list((out / "bags").glob("*.json"))) < 12
    assert not {pid for pid in workers if _running(pid)}


# --- 5: workers die with their parent -------------------------------------------------------------
def _children(pid: int) -> set[int]:
    found = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.add(int(entry.name))
    return found


def _descendants(pid: int) -> set[int]:
    found, todo = set(), [pid]
    while todo:
        children = _children(todo.pop())
        found |= children
        todo.extend(children)
    return found


def _started(pid: int) -> set[int]:
    """The children of ``pid`` with more than one thread (a pool worker past ``die_with_parent``)."""
    found = set()
    for child in _children(pid):
        try:
            status = Path(f"/proc/{child}/status").read_text()
        except OSError:
            continue
        threads = [line.split()[1] for line in status.splitlines() if line.startswith("Threads:")]
        if threads and int(threads[0]) > 1:
            found.add(child)
    return found


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _kill_and_watch(proc: subprocess.Popen[str], workers: set[int], limit: float = 20) -> set[int]:
    """SIGKILL ``proc``; the ``workers`` still running ``limit`` seconds later."""
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline and any(_running(pid) for pid in workers):
        time.sleep(0.1)
    alive = {pid for pid in workers if _running(pid)}
    for pid in alive:  # leave nothing behind, whatever the outcome
        os.kill(pid, signal.SIGKILL)
    return alive


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc to find the workers")
@pytest.mark.parametrize("single_thread", [True, False], ids=["forked", "fork_server"])
def test_the_workers_of_a_killed_batch_run_exit(lab: dict[str, Path], tmp_path: Path,
                                                single_thread: bool) -> None:
    bags, out = _many(tmp_path / "many", 12), tmp_path / "seg"
    proc = _segment(lab, bags, out, "--jobs", "2", single_thread=single_thread)
    _wait_for_records(out, proc)
    workers = _descendants(proc.pid)
    assert len(workers) >= 2, "the run started no worker"
    assert not _kill_and_watch(proc, workers)


_CACHE_BUILD = """
import sys
from ompn_ros.data import ReaderSpec
from ompn_ros.data.cache import load_arrays
import yaml
spec = ReaderSpec.from_dict(yaml.safe_load(open(sys.argv[2])))
load_arrays(sys.argv[1], spec=spec, cache_dir=sys.argv[3], workers=2)
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc to find the workers")
def test_the_cache_workers_of_a_killed_training_exit(lab: dict[str, Path], tmp_path: Path) -> None:
    """``data.cache_workers: 2``: the per-bag cache's worker processes end with a killed ``ompn_train``."""
    bags = _many(tmp_path / "many", 24, steps=90)
    proc = subprocess.Popen([sys.executable, "-c", _CACHE_BUILD, str(bags), str(lab["spec"]),
                             str(tmp_path / "cache")], env=_env(), text=True)
    # Killed once two workers have run their initializer (die_with_parent starts a watchdog thread),
    # not after a fixed sleep: the workers import no torch, a bag takes them milliseconds and a
    # second's wait outlasted the whole build.
    deadline = time.monotonic() + 60
    while len(_started(proc.pid)) < 2 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.01)
    workers = _children(proc.pid)
    assert proc.poll() is None and len(_started(proc.pid)) >= 2, "the cache build started no workers"
    assert not list((tmp_path / "cache").glob("episodes_set_*")), "killed after the build"
    assert not _kill_and_watch(proc, workers)


# --- 6: symbolic link loops -----------------------------------------------------------------------
def test_a_link_loop_lists_every_bag_once(lab: dict[str, Path], tmp_path: Path) -> None:
    folder = tmp_path / "lab"
    shutil.copytree(lab["bags"], folder)
    (folder / "again").symlink_to(folder)  # a loop back up the tree
    (folder / "b_alias").symlink_to(folder / "b")  # a second path to one bag
    assert sorted(b.key for b in list_bags(str(folder))) == ["a", "b", "c"]


def test_two_link_loops_list_quickly(lab: dict[str, Path], tmp_path: Path) -> None:
    """Two loops: every path through them is another name of the same folder (2^40 of them)."""
    folder = tmp_path / "lab"
    shutil.copytree(lab["bags"], folder)
    (folder / "x").symlink_to(".")
    (folder / "y").symlink_to(".")
    code = ("import sys; from ompn_ros.app.batch_bags import list_bags; "
            "print([len(list_bags(source)) for source in sys.argv[1:]])")
    sources = [str(folder), f"{folder}/**/metadata.yaml"]  # a folder, a recursive glob
    done = subprocess.run([sys.executable, "-c", code, *sources], env=_env(), capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0 and done.stdout.strip() == "[3, 3]", done.stderr[-2000:]


# --- 7: bags that vanish, dangle, cannot be read ---------------------------------------------------
def test_a_dangling_link_is_refused_on_its_own_line_and_reruns_go_on(
        lab: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "lab"
    shutil.copytree(lab["bags"], folder)
    (folder / "gone.mcap").symlink_to(tmp_path / "nowhere.mcap")
    for _ in range(2):  # the run, then a rerun
        assert main(["--bags", str(folder), *_args(lab, tmp_path / "seg")]) == 1
        err = capsys.readouterr().err
        summary = json.loads((tmp_path / "seg" / "summary.json").read_text())
        assert summary["segmented"] == 3
        assert [r["bag"] for r in summary["refused"]] == [str(folder / "gone.mcap")]
        assert "Traceback" not in err and "gone: refused: " in err


def test_a_bag_deleted_mid_run_is_refused_and_the_run_goes_on(lab: dict[str, Path], tmp_path: Path) -> None:
    folder = tmp_path / "lab"
    shutil.copytree(lab["bags"], folder)
    bags = list_bags(str(folder))
    settings = BatchSettings(checkpoint=str(lab["model"]), detector=DetectorConfig(), out=tmp_path / "seg",
                             reader_config=str(lab["spec"]))

    def delete_the_next(doc: dict[str, Any], done: int, total: int) -> None:
        if done == 1:
            shutil.rmtree(folder / "b")

    docs = run_batch(settings, bags, 1, progress=delete_the_next)
    assert [(d["key"], d["status"]) for d in docs] == [("a", "segmented"), ("b", "refused"),
                                                       ("c", "segmented")]
    assert str(folder / "b") in docs[1]["reason"]


_LIST = """
import json, os, sys
from ompn_ros.app.batch_bags import list_bags
if os.geteuid() == 0:  # root reads any folder: list as an unprivileged user
    os.setgid(65534)
    os.setuid(65534)
print(json.dumps([[b.key, b.path is None, b.problem] for b in list_bags(sys.argv[1])]))
"""


def test_an_unreadable_bag_folder_is_refused_on_its_own(lab: dict[str, Path]) -> None:
    """A bag folder its reader may not open (mode 000) among readable ones."""
    shared = Path(tempfile.mkdtemp(prefix="ompn_unreadable_"))
    try:
        shared.chmod(0o755)
        shutil.copytree(lab["bags"], shared / "lab")
        for path in [shared / "lab", *(shared / "lab").rglob("*")]:
            path.chmod(0o755 if path.is_dir() else 0o644)
        (shared / "lab" / "b").chmod(0)
        done = subprocess.run([sys.executable, "-c", _LIST, str(shared / "lab")], env=_env(),
                              capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr[-2000:]
        listed = json.loads(done.stdout)
        assert [key for key, refused, _ in listed if not refused] == ["a", "c"]
        [(key, _, problem)] = [item for item in listed if item[1]]
        assert key == "b" and "Permission denied" in problem and str(shared / "lab" / "b") in problem
    finally:
        (shared / "lab" / "b").chmod(0o755)
        shutil.rmtree(shared)


# --- 8: --annotate on a full disk -----------------------------------------------------------------
def test_annotate_on_a_full_disk_is_one_line_per_bag(
        lab: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with small_disk(tmp_path / "small", size_kb=64, free_kb=8) as disk:
        code = main(["--bag", str(lab["bags"] / "a"), "--annotate", str(disk / "copy"),
                     *_args(lab, tmp_path / "one")])
        err = capsys.readouterr().err
        assert code == 2 and "Traceback" not in err, err[-3000:]
        [line] = [line for line in err.splitlines() if "error:" in line]
        assert "copy" in line and "No space left on device" in line
        assert sorted(p.name for p in disk.iterdir()) == ["filler"]  # nothing partial left
        code = main(["--bags", str(lab["bags"]), "--annotate", str(disk / "copies"),
                     *_args(lab, tmp_path / "many")])
        err = capsys.readouterr().err
        assert code == 1 and "Traceback" not in err and "a bug" not in err, err[-3000:]
        summary = json.loads((tmp_path / "many" / "summary.json").read_text())
        assert len(summary["refused"]) == 3
        assert all("No space left on device" in r["reason"] for r in summary["refused"])
        assert not list((disk / "copies").iterdir())


# --- 9: two annotating runs into one folder at once -----------------------------------------------
def test_two_writers_of_one_annotated_copy_each_finish_whole(
        lab: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A second run writes the same copy while the first is in the middle of writing it."""
    from ompn_ros.app.annotate import annotate_bag, observation_stamps
    from ompn_ros.app.replay import replay_all
    from ompn_ros.data import ReaderSpec, read_episodes
    from ompn_ros.model.load import stepper_from_checkpoint

    spec = ReaderSpec.from_yaml(lab["spec"])
    episodes = read_episodes(lab["bags"] / "a", spec=spec).episodes
    replays = replay_all(stepper_from_checkpoint(lab["model"]), episodes, DetectorConfig())
    stamps = observation_stamps(lab["bags"] / "a", episodes, topic=spec.observation.topic,
                                namespace=spec.namespace)
    pairs = list(zip(stamps, replays, strict=True))
    out = tmp_path / "copies" / "a"
    out.parent.mkdir()
    copy = annotate_module._copy_connections
    nested: list[Any] = []

    def write_while_another_writes(*args: Any) -> Any:  # the first writer has its bag open
        if not nested:
            nested.append(None)
            nested[0] = annotate_bag(lab["bags"] / "a", out, pairs, overwrite=True)
        return copy(*args)

    monkeypatch.setattr(annotate_module, "_copy_connections", write_while_another_writes)
    report = annotate_bag(lab["bags"] / "a", out, pairs, overwrite=True)
    assert nested and report.out == nested[0].out == out
    assert sorted(p.name for p in out.parent.iterdir()) == ["a"]  # no staging folder left
    again = read_episodes(out, spec=spec).episodes
    assert [ep.length for ep in again] == [ep.length for ep in episodes]


def test_two_annotating_runs_into_one_folder(lab: dict[str, Path], tmp_path: Path) -> None:
    folder = _many(tmp_path / "many", 6, steps=30)
    copies = tmp_path / "copies"
    procs = [_segment(lab, folder, tmp_path / "seg", "--annotate", str(copies)) for _ in range(2)]
    outputs = [proc.communicate(timeout=300) for proc in procs]
    for proc, (_, err) in zip(procs, outputs, strict=True):
        assert proc.returncode == 0 and "Errno" not in err, err[-3000:]
    assert sorted(p.name for p in copies.iterdir()) == [f"run{i:02d}" for i in range(6)]
    assert all((copies / f"run{i:02d}" / "metadata.yaml").is_file() for i in range(6))
    assert json.loads((tmp_path / "seg" / "summary.json").read_text())["segmented"] == 6
    assert not [p for p in (tmp_path / "seg" / "bags").iterdir() if p.name.startswith(".")]
