"""ROS 2 plumbing shared by every node of this package and both sims: the parameter helper
(:mod:`.params`), the one ``main()`` of every node (:mod:`.run`), the Fast DDS containment environment
(:mod:`.containment`, :mod:`.env`) and the launch description (:mod:`.launch_sim`).  Nothing here
imports a node or a command.
"""
