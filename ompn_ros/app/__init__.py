"""The services the ``ompn_*`` commands run: demonstrations into bags (:mod:`.collect`), training runs
(:mod:`.training`), replay of bags through the segmenter (:mod:`.replay`), many bags at once
(:mod:`.batch`, :mod:`.batch_bags`, :mod:`.batch_table`), annotated copies of bags (:mod:`.annotate`),
the live demo (:mod:`.live`) and closed-loop evaluation (:mod:`.closed_loop`, :mod:`.closed_loop_ros`).

The command-line shells in :mod:`ompn_ros.cli` import these; the services import the library below
them (data, model, detect, train, segmenter) and never a command or a node.
"""
