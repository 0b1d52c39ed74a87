"""The live segmentation demo run from its parsed options: ``ompn_live_demo`` and ``ompn_demo``.

The options are :func:`ompn_ros.cli._common.add_live_demo_arguments`; the work is
:func:`ompn_ros.app.live.run_demo`.
"""

from __future__ import annotations

import argparse

from ompn_ros.app import live
from ompn_ros.checkpoints import shipped_checkpoint


def run_live_demo(args: argparse.Namespace) -> int:
    """The live demo for parsed arguments (the shipped checkpoint of ``--domain`` without
    ``--checkpoint``)."""
    checkpoint = args.checkpoint or shipped_checkpoint(args.domain)
    return live.run_demo(args.domain, checkpoint, args.episodes, args.rate, args.seed, args.out, args.timeout,
                         params_file=args.params_file, sim_params=args.sim_param)
