"""rosbag2 -> Episodes, one module per job (the rules are in :mod:`ompn_ros.data.bag_reader`).

``spec`` (what to read), ``paths`` (where the bags are), ``raw`` / ``salvage`` (undecoded
messages), ``plan`` / ``columns`` (the step topic decoded while the bag is read, its bytes dropped),
``context`` (topic resolution and type checks), ``decode`` / ``joints`` / ``vectors``
(arrays, corrupt tail), ``observe`` (observations from several topics, ``ReaderSpec.assemble``),
``align`` (partners, episode windows), ``assemble`` (episodes), ``report`` (what was used), ``read``
(entry points).
"""
