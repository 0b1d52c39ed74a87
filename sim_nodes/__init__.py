"""Simulated domains (Craft, Dial) and their ROS 2 sim nodes.

Everything here except ``*/node.py`` and ``ros_common.py`` is ROS-free.

The two packages meet at two small interfaces (``test/house/test_import_graph.py`` checks both):

* **sim_nodes -> ompn_ros**: only these public modules of ``ompn_ros`` are imported here:

  - ``ompn_ros.layout``: topic names, types and sizes, the step contract, sketch vocabularies;
  - ``ompn_ros.errors``: the root of the error tree (a bad task or Dial setting is a user's error);
  - ``ompn_ros.data.episode``: the :class:`~ompn_ros.data.episode.Episode` the experts return;
  - ``ompn_ros.data.messages``: the ROS-free CDR message codec;
  - ``ompn_ros.validate``: the sketch validator (Dial's ``sketch`` parameter);
  - ``ompn_ros.ros.params`` and ``ompn_ros.ros.run`` (sim nodes only): the parameter helper and the
    one ``main()`` of every node, :func:`~ompn_ros.ros.run.run_node`.

* **ompn_ros -> sim_nodes**: ``ompn_ros`` imports only :mod:`sim_nodes.registry` (expert episodes
  by domain name, the envs, task lists, :func:`derive_seed`); the sim nodes themselves are started
  as processes, never imported.
"""

from __future__ import annotations

import numpy as np

SEED_MAX = 2**31 - 1
"""Seeds are kept in the non-negative int32 range so they fit ROS integer parameters and markers."""


def derive_seed(seed: int, index: int, *, stream: int = 0) -> int:
    """A reproducible child seed in ``[0, SEED_MAX]`` for item ``index`` of ``seed``.

    ``stream`` separates independent uses (e.g. 0 = the n-th episode of a run, 1 = the n-th retry of
    an episode), so derived seeds of different purposes do not collide systematically.
    """
    if seed < 0 or index < 0 or stream < 0:
        raise ValueError(
            f"derive_seed needs non-negative ints, got seed={seed} index={index} stream={stream}"
        )
    state = np.random.SeedSequence([int(seed), int(index), int(stream), 0x0B5C]).generate_state(1)
    return int(state[0]) & SEED_MAX
