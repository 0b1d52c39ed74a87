"""The research lab: the reproduction of the paper's tables (Lu et al., ICLR 2021, §4) and the studies
recorded in ``docs/experiments.md``.  It lives beside the ``ompn_ros`` package and is not installed:
run it from a checkout (``make reproduce-craft``, ``python -m lab.reproduce``).  It uses the product
(``ompn_ros``); the product never imports it.

One job per module (study -> module -> results file -> docs/experiments.md section: ``lab/README.md``):

* :mod:`~lab.spec`: the settings of the paper's tables, validated run specifications;
* :mod:`~lab.data`: demonstrations in bags, read back, the held-out split;
* :mod:`~lab.runs`: train or reload one run of the reproduction;
* :mod:`~lab.scoring`, :mod:`~lab.ensembles`, :mod:`~lab.sweeps`, :mod:`~lab.replayed`: held-out
  scores (offline, constrained, online; ensembles; the appendix sweeps; a run replayed as the node
  runs it);
* :mod:`~lab.report`, :mod:`~lab.report_own`, :mod:`~lab.report_hparams`, :mod:`~lab.report_selection`,
  :mod:`~lab.report_final_auto`, :mod:`~lab.report_transfer`, :mod:`~lab.report_head`,
  :mod:`~lab.figures`, :mod:`~lab.hparams_figure`: result files, ``results/README.md``, plots;
* :mod:`~lab.ship`, :mod:`~lab.ship_product`: a checkpoint shipped in the package (from a lab run, or
  made by the product's own commands);
* :mod:`~lab.pipeline`: the reproduction's stages in order (:mod:`~lab.reproduce`, its command line);
* :mod:`~lab.reproduce_product`: the reproduction through the product's own commands (``ompn_collect``,
  ``ompn_train``, ``ompn_segment`` with the detector the training bundled; ``make reproduce-*``);
* :mod:`~lab.own_data`, :mod:`~lab.strip`, :mod:`~lab.subsets`, :mod:`~lab.fresh`,
  :mod:`~lab.hparams`: the own-data, stripped-bag, subset, fresh-data and memory-size studies;
* :mod:`~lab.detector_selection`, :mod:`~lab.final_auto`, :mod:`~lab.warmup_check`,
  :mod:`~lab.budget_check`, :mod:`~lab.transfer`: choosing the online detector, ``final_observation:
  auto``, the agreement warm-up and the delay budget where they were not tuned, the transfer table;
* :mod:`~lab.boundary_head`, :mod:`~lab.head_check`, :mod:`~lab.head_duration`: the boundary head,
  its product path end to end, and the duration decoder over it;
* :mod:`~lab.human_gap`, :mod:`~lab.detours`: where the human-like gap comes from, and detours.
"""
