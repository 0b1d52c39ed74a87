"""Writing bags: the durable writer (:mod:`.bag_writer`, :mod:`.storage`: chunk CRCs, periodic commits)
and the parts of ``bag_recorder`` (:mod:`.recording`: the bag being recorded, through :mod:`.stop_cut`
and :mod:`.step_commits`, guarded by :mod:`.disk_guard`; :mod:`.sim_stamps`).
"""
