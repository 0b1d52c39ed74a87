"""The stream rule: stamps, episode cuts, markers and resets over a
:class:`~ompn_ros.segmenter.StreamingSegmenter`.

ROS-free, shared by ``ompn_node`` (:mod:`ompn_ros.stream.rule`) and the offline replay
(:mod:`ompn_ros.stream.replay`), so a recorded stream replayed with its stamps gives what the node
published for it.  The pause, idle and still rules: :mod:`ompn_ros.data.cuts`.
"""
