"""`ros2 run beams_bringup robot`: driver_node, triangulation_node and ekf_node as nodes of one process on
one executor (`one_process:=true`, beams_tools.robot_processes.ONE_PROCESS; docs/integrity.md)."""

import sys

from beams_common.ros.node_support import run_node
from beams_driver.driver_node import DriverNode
from beams_ekf.ekf_node import EkfNode
from beams_triangulation.triangulation_node import TriangulationNode

# destroyed in the reverse order: the EKF stops (its checkpoint written) before its inputs
NODES = (DriverNode, TriangulationNode, EkfNode)


def main(args: list[str] | None = None) -> None:
    sys.exit(run_node(NODES, args))
