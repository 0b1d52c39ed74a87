"""Stopping a node started as a child process by a test: SIGINT, then its output."""

from __future__ import annotations

import signal
import subprocess


def interrupt(proc: subprocess.Popen[str], timeout: float = 10.0) -> str:
    """Send SIGINT to ``proc`` if it still runs, wait up to ``timeout`` s (then kill it), return its
    output."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out
