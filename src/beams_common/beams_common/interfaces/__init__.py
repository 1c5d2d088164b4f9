"""The names and shapes on the wire: every topic and service name (`topics`) and the one builder of
beams/bearings messages, for rclpy's classes and rosbags' types alike (`bearing_messages`).
"""
