"""The plane the robot lives in: angles, SE(2) poses, the stamped pose buffer (interpolation, arc
extrapolation), the beacon map and the one Bearing type. Pure maths shared by the sensor, ToTal, the EKF
and the simulator: nothing here knows of messages, files, checks or ROS. A geometric concept two packages
use belongs here.
"""
