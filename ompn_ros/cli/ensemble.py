"""``ompn_ensemble``: write an ensemble checkpoint directory from trained checkpoints.

    ompn_ensemble --out runs/ensemble runs/seed0/best runs/seed1/best runs/seed2/best

The directory holds only ``ensemble.json`` (member paths relative to it); ``ompn_node``'s
``checkpoint`` parameter and ``ompn_segment --checkpoint`` accept it like a single checkpoint (see
:mod:`ompn_ros.model.ensemble`).  The members must share obs_dim, n_slots, action type and size and
sketch mode.  An ensemble wants its own online-detector settings: ``ompn_segment --tune
--checkpoint <the directory>`` on labelled episodes none of the members was trained on.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ompn_ros.model.checkpoint import CheckpointError


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ompn_ensemble", description=__doc__.splitlines()[0])
    p.add_argument("members", nargs="+", type=Path, help="member checkpoint directories (at least 2)")
    p.add_argument("--out", type=Path, required=True, help="ensemble directory to write")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from ompn_ros.model.checkpoint import load_config
    from ompn_ros.model.ensemble import write_ensemble

    try:
        command = ["ompn_ensemble", *(sys.argv[1:] if argv is None else argv)]
        target = write_ensemble(args.out, args.members, {"command": command})
        config = load_config(args.members[0])
    except CheckpointError as exc:
        print(f"ompn_ensemble: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {target}: {len(args.members)} members, obs_dim={config.obs_dim} n_slots={config.n_slots} "
          f"action={config.action_type}({config.action_dim}) sketch_mode={config.sketch_mode}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
