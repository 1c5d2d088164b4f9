"""What comes in is checked once, here, and every consumer (the nodes, the offline replay, the benches) sees
the same verdict: a revolution's bearings (`bearing_intake`), a pose offered to a filter (`pose_intake`),
odometry and the published-pose invariant (`validation`), well-formed values that cannot be true
(`plausibility`: stamps against the receiving clock, increments against the robot's limits), stamp order
(`time_jumps`) and two sources in one stream (`stream_interleave`). A new rule about an input goes in
that input's intake, returning a reason.
"""
