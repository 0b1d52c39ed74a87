"""The live segmentation demo's options and its run from them: ``ompn_live_demo`` and ``ompn_demo``.

The options are :func:`add_live_demo_arguments`; the work is :func:`ompn_ros.app.live.run_demo`.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from ompn_ros.app import live


def run_live_demo(args: argparse.Namespace) -> int:
    """The live demo for parsed arguments (the shipped checkpoint of ``--domain`` without
    ``--checkpoint``)."""
    return live.run_demo(args.domain, args.checkpoint, args.episodes, args.rate, args.seed, args.out,
                         args.timeout, params_file=args.params_file, sim_params=args.sim_param)


def add_live_demo_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The options of the live segmentation demo (``ompn_demo`` and ``python -m ompn_ros.cli.live_demo``)."""
    parser.add_argument("--domain", choices=sorted(live.DOMAINS), default="dial", help="which simulator")
    parser.add_argument("--episodes", type=int, default=3, help="episodes to segment")
    parser.add_argument("--rate", type=float, default=100.0, help="sim rate in Hz (Dial real time is 25)")
    parser.add_argument("--seed", type=int, default=1000, help="first episode seed (held out from training)")
    parser.add_argument(
        "--checkpoint", type=Path, default=None, help="checkpoint directory (none: the shipped one)"
    )
    parser.add_argument(
        "--out", type=Path, default=Path("out/demo"), help="directory of the summary and plot"
    )
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds to wait for the episodes")
    parser.add_argument(
        "--params-file", type=Path, default=None,
        help="ompn_node parameters file (none: config/ompn_node_<domain>.yaml)",
    )
    parser.add_argument(
        "--sim-param", type=sim_param, action="append", default=[], metavar="NAME:=VALUE",
        help="a parameter of the sim, repeatable (e.g. full_obs:=false, task:=makeaxe); "
             f"{', '.join(LIVE_SIM_PARAMS)} are set by the other options",
    )
    return parser


LIVE_SIM_PARAMS = ("mode", "rate", "seed", "episodes", "wait_for_subscribers", "wait_topics")
"""The sim parameters the live demo sets itself (``ompn_ros.app.live.launch``)."""
_SIM_PARAM = re.compile(r"[A-Za-z_][A-Za-z0-9_]*:=\S.*")


def sim_param(text: str) -> str:
    """``NAME:=VALUE`` for the sim's ``--ros-args -p``; the sim validates the value when it starts."""
    if not _SIM_PARAM.fullmatch(text):
        raise argparse.ArgumentTypeError(f"{text!r} is not NAME:=VALUE")
    name = text.split(":=", 1)[0]
    if name in LIVE_SIM_PARAMS:
        raise argparse.ArgumentTypeError(f"{name} is set by the demo's own options, not by --sim-param")
    return text
