"""Chapter-7 calibration of BeAMS as ROS services: power bias, rotation bias, turret offset, beacons."""
