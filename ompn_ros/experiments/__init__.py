"""The reproduction of the paper's tables as a library (``ompn_reproduce`` is its command line).

One job per module: :mod:`~ompn_ros.experiments.spec` (settings, validated run specifications),
:mod:`~ompn_ros.experiments.data` (bags, held-out split), :mod:`~ompn_ros.experiments.runs`
(train or reload one run), :mod:`~ompn_ros.experiments.scoring` (held-out metrics: offline,
constrained, online), :mod:`~ompn_ros.experiments.ensembles`, :mod:`~ompn_ros.experiments.sweeps`,
:mod:`~ompn_ros.experiments.report` (result schema, JSON, ``results/README.md``),
:mod:`~ompn_ros.experiments.ship` and :mod:`~ompn_ros.experiments.pipeline` (the stages in order).
"""
