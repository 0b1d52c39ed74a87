"""The library behind the ``ompn_*`` commands: the reproduction of the paper's tables (Lu et al.,
ICLR 2021, §4) and the data, training, replay and live runs the commands start.

One job per module:

* :mod:`~ompn_ros.experiments.spec`: the settings of the paper's tables, validated run specifications;
* :mod:`~ompn_ros.experiments.collect` / :mod:`~ompn_ros.experiments.data`: demonstrations in bags,
  read back, the held-out split;
* :mod:`~ompn_ros.experiments.training`: config files and behaviour cloning (``ompn_train``);
* :mod:`~ompn_ros.experiments.runs`: train or reload one run of the reproduction;
* :mod:`~ompn_ros.experiments.scoring`, :mod:`~ompn_ros.experiments.ensembles`,
  :mod:`~ompn_ros.experiments.sweeps`: held-out scores (offline, constrained, online);
* :mod:`~ompn_ros.experiments.replay`: replay through the ``StreamingSegmenter`` (``ompn_segment``);
* :mod:`~ompn_ros.experiments.report` and :mod:`~ompn_ros.experiments.figures`: result files,
  ``results/README.md``, plots;
* :mod:`~ompn_ros.experiments.ship`: a checkpoint shipped in the package;
* :mod:`~ompn_ros.experiments.pipeline`: the reproduction's stages in order (``ompn_reproduce``);
* :mod:`~ompn_ros.experiments.live`: the live demo over ROS 2 (ROS imported only there, when run).
"""
