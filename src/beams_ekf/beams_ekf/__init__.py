"""EKF (filterpy) fusing wheel odometry with every BeAMS bearing."""
