"""The reference layout of the thesis's calibration (section 7.3.1): the a-priori beacons of table 7.1, the
twelve reference positions of table 7.2 and the four orientations of eq. 7.3. The guided session scales
its plan from them (session.reference_plan); beams_thesis.thesis_setup builds the thesis's experiment on
them."""

import numpy as np

from beams_common.geometry.beacon_map import BeaconMap

# Table 7.1: a-priori beacon coordinates (m).
PRIOR_BEACONS = BeaconMap.from_lists((1, 2, 3), (1.151, 0.600, 0.049), (0.049, 0.907, 0.049))
# Table 7.2: reference positions (m).
REFERENCE_POSITIONS = np.array(
    [
        (0.12, 0.84),
        (1.08, 0.84),
        (0.36, 0.76),
        (0.84, 0.76),
        (0.20, 0.52),
        (0.44, 0.52),
        (0.76, 0.52),
        (1.00, 0.52),
        (0.60, 0.36),
        (0.28, 0.20),
        (0.92, 0.20),
        (0.60, 0.12),
    ]
)
# Eq. 7.3: reference orientations (rad).
REFERENCE_ORIENTATIONS = (0.0, np.pi / 2, np.pi, -np.pi / 2)
