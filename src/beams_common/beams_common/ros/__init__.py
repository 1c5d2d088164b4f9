"""The ROS plumbing: running a node (its role and hot standby: `standby`, `node_support`), declaring
and changing parameters from a table, guarded callbacks, /diagnostics and the status topics, message
conversions. The only part of beams_common that imports rclpy (`standby` excepted: it runs before it).
"""
