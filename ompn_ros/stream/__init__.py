"""The stream rule: stamps, episode cuts, markers and resets over a
:class:`~ompn_ros.segmenter.StreamingSegmenter`.

ROS-free, shared by ``ompn_node`` (:mod:`ompn_ros.stream.rule`) and the offline replay
(:mod:`ompn_ros.stream.replay`), so a recorded stream replayed with its stamps gives what the node
published for it.  The pause and idle rules: :mod:`ompn_ros.stream.gap`.
"""
