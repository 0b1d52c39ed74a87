"""ompn_ensemble: write an ensemble checkpoint directory from trained checkpoints.

    ompn_ensemble --out runs/ensemble runs/seed0/best runs/seed1/best runs/seed2/best

The directory holds only ensemble.json (member paths relative to it); ompn_node's checkpoint
parameter and ompn_segment --checkpoint accept it like a single checkpoint (see
ompn_ros.model.ensemble).  The members must share obs_dim, n_slots, action type and size and
sketch mode.  The directory starts with the first member's detector settings (detector.json);
an ensemble wants its own: ompn_segment --tune --write-config FILE --checkpoint <the directory>
on labelled episodes none of the members was trained on stores them there.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from ompn_ros.cli._common import make_parser, run_cli


def build_parser() -> argparse.ArgumentParser:
    p = make_parser("ompn_ensemble", __doc__.splitlines()[0])
    p.add_argument("members", nargs="+", type=Path, help="member checkpoint directories (at least 2)")
    p.add_argument("--out", type=Path, required=True, help="ensemble directory to write")
    return p


def _run(args: argparse.Namespace) -> int:
    from ompn_ros.app.ensemble import write_ensemble_dir  # here: --help stays light

    target, config = write_ensemble_dir(args.out, args.members, {"command": args.command_line})
    print(
        f"wrote {target}: {len(args.members)} members, obs_dim={config.obs_dim} n_slots={config.n_slots} "
        f"action={config.action_type}({config.action_dim}) sketch_mode={config.sketch_mode}"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run_cli(build_parser(), _run, argv)


if __name__ == "__main__":
    sys.exit(main())
