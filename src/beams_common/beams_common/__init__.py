"""Shared concepts of the BeAMS suite, pure, one sub-package per concept: `geometry` (angles, SE(2) poses, the
pose buffer, the beacon map, the Bearing type), `intake` (the one check of every input), `status` (the
health model), `calibration` (the calibration file, its schema and checks, the corrections it describes),
`config` (parameter specs and tables), `interfaces` (topic names, message builders); `ros` is the ROS
plumbing, the only part that imports rclpy.
"""
