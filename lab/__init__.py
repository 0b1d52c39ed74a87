"""The research lab: the reproduction of the paper's tables (Lu et al., ICLR 2021, §4) and the studies
recorded in ``docs/experiments.md``.  It lives beside the ``ompn_ros`` package and is not installed:
run it from a checkout (``make reproduce-craft``, ``python -m lab.reproduce``).  It uses the product
(``ompn_ros``); the product never imports it.

One job per module:

* :mod:`~lab.spec`: the settings of the paper's tables, validated run specifications;
* :mod:`~lab.data`: demonstrations in bags, read back, the held-out split;
* :mod:`~lab.runs`: train or reload one run of the reproduction;
* :mod:`~lab.scoring`, :mod:`~lab.ensembles`, :mod:`~lab.sweeps`: held-out scores (offline,
  constrained, online);
* :mod:`~lab.report`, :mod:`~lab.report_own`, :mod:`~lab.report_hparams` and :mod:`~lab.figures`:
  result files, ``results/README.md``, plots;
* :mod:`~lab.ship`: a checkpoint shipped in the package;
* :mod:`~lab.pipeline`: the reproduction's stages in order (:mod:`~lab.reproduce`, its command line);
* :mod:`~lab.own_data`, :mod:`~lab.strip`, :mod:`~lab.subsets`, :mod:`~lab.fresh`,
  :mod:`~lab.hparams`: the own-data, subset, fresh-data and memory-size studies.
"""
