"""Writing bags: the durable writer (:mod:`.bag_writer`, :mod:`.storage`: chunk CRCs, periodic commits)
and the parts of ``bag_recorder`` (:mod:`.stop_cut`, :mod:`.step_commits`, :mod:`.sim_stamps`,
:mod:`.disk_guard`).
"""
