"""Chapter-7 calibration of BeAMS (power bias, rotation bias, turret offset, beacon coordinates) as ROS services."""
