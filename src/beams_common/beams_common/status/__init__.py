"""A localisation node's status that means something: the health model (waiting / tracking / degraded /
lost, rate monitors, held faults) and throttled logging. What a node publishes about itself is decided
here, without ROS; `beams_common.ros` puts it on /diagnostics and the status topics.
"""
