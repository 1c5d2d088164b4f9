"""Every topic and service name of the suite, in one place (REP-144 style relative names, so a robot's
namespace applies; the ROS-wide ones are absolute).

Services that act on one node live under that node's private name (`~/`): `/ekf_node/set_pose`, or
`/robot1/ekf_node/set_pose` in a robot's namespace.
"""

# topics between the nodes (relative: one robot per namespace)
BEARINGS = "beams/bearings"
POSE = "beams/pose"
POSE_COV = "beams/pose_cov"
MARKERS = "beams/markers"
EKF_ODOMETRY = "beams/ekf/odometry"
EKF_POSE = "beams/ekf/pose"
# each localisation node's status beside its estimates (beams_msgs/LocalisationStatus, latched)
EKF_STATUS = "beams/ekf/status"
TRIANGULATION_STATUS = "beams/triangulation/status"
ODOMETRY = "odom"
GROUND_TRUTH = "beams/sim/ground_truth"
# ROS-wide topics
DIAGNOSTICS = "/diagnostics"
TF = "/tf"
INITIAL_POSE = "/initialpose"

# node services (private)
RELOAD_CALIBRATION = "~/reload_calibration"
SET_POSE = "~/set_pose"
RESET = "~/reset"
# ekf_node: write the power bias learnt while driving as a calibration file
SAVE_CALIBRATION = "~/save_calibration"
CAPTURE_REFERENCE = "~/capture_reference"
CALIBRATE = "~/calibrate"
LIST_CONFIGURATIONS = "~/list_configurations"
CLEAR_DATASET = "~/clear_dataset"
