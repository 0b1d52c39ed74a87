"""``--help`` of every console script loads no torch (the seconds it costs; timings: bench/bench_startup.py).

Each entry point of setup.py runs as its console-script wrapper runs it, in a fresh interpreter, with
``--help``; the test reads which heavy modules were imported on the way.  Before, ``ompn_node``,
``ompn_segment``, ``ompn_train``, ``ompn_ensemble`` and ``ompn_closed_loop`` all loaded torch (10-15 s
on a busy 2-core machine) to print their help.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("torch", "matplotlib")


def _entry_points() -> dict[str, str]:
    """``name -> module:function`` of setup.py's console_scripts (read, not imported)."""
    tree = ast.parse((ROOT / "setup.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values, strict=True):
                if isinstance(key, ast.Constant) and key.value == "console_scripts":
                    scripts = ast.literal_eval(value)
                    return dict(s.replace(" ", "").split("=", 1) for s in scripts)
    raise AssertionError("setup.py has no console_scripts")


ENTRIES = _entry_points()


def test_every_console_script_is_checked() -> None:
    assert {"ompn_node", "ompn_segment", "ompn_train", "ompn_collect", "dial_sim", "craft_sim"} \
        <= set(ENTRIES)


@pytest.mark.parametrize("name", sorted(ENTRIES))
def test_help_loads_no_torch(name: str) -> None:
    module, func = ENTRIES[name].split(":")
    probe = (
        f"import json, sys\nfrom {module} import {func}\nsys.argv = [{name!r}, '--help']\n"
        f"try:\n    code = {func}()\nexcept SystemExit as exc:\n    code = exc.code\n"
        f"print(json.dumps([code, sorted(m for m in {HEAVY!r} if m in sys.modules)]))\n"
    )
    result = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True,
                            timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert result.returncode == 0, result.stderr
    code, heavy = json.loads(result.stdout.strip().splitlines()[-1])
    assert code in (0, None), result.stdout
    assert "usage" in result.stdout.lower() or "parameters" in result.stdout.lower(), result.stdout[:500]
    assert heavy == [], f"{name} --help imported {heavy}"
