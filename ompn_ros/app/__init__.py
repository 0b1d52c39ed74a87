"""The services the ``ompn_*`` commands run: demonstrations into bags (:mod:`.collect`), training runs
(:mod:`.training`), ensemble directories (:mod:`.ensemble`), replay of bags through the segmenter
(:mod:`.segment_setup`, :mod:`.replay`), detector tuning (:mod:`.detector_tuning`), many bags at once
(:mod:`.batch`, :mod:`.batch_bags`, :mod:`.batch_table`), annotated copies of bags (:mod:`.annotate`),
the live demo (:mod:`.live`), the DDS self-check (:mod:`.dds_check`) and closed-loop evaluation
(:mod:`.closed_loop`, :mod:`.closed_loop_ros`).

The command-line shells in :mod:`ompn_ros.cli` import only these (and :mod:`ompn_ros.errors`): the
constants a parser offers as choices or defaults are part of the service's API (e.g.
``collect.STORAGES``).  The services import the library below them (data, model, detect, train,
segmenter) and never a command or a node.
"""
