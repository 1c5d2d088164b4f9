"""A separate process for test_interfaces.py: echoes every beams_msgs message and answers every service.

Messages received on `echo_in/<Type>` are republished unchanged on `echo_out/<Type>`; services answer
with values derived from the request so the test can check both directions.
"""

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from beams_msgs.msg import BeaconBearing, BeaconBearingArray, LocalisationStatus, TriangulatedPose
from beams_msgs.srv import Calibrate, CaptureReference, ListConfigurations

MESSAGE_TYPES = (BeaconBearing, BeaconBearingArray, TriangulatedPose, LocalisationStatus)


class InterfaceEcho(Node):
    def __init__(self) -> None:
        super().__init__("interface_echo")
        for msg_type in MESSAGE_TYPES:
            publisher = self.create_publisher(msg_type, f"echo_out/{msg_type.__name__}", 10)
            self.create_subscription(msg_type, f"echo_in/{msg_type.__name__}", publisher.publish, 10)
        self.create_service(CaptureReference, "echo/capture_reference", self.capture_reference)
        self.create_service(Calibrate, "echo/calibrate", self.calibrate)
        self.create_service(ListConfigurations, "echo/list_configurations", self.list_configurations)

    def capture_reference(self, request: CaptureReference.Request, response: CaptureReference.Response):
        response.success = True
        response.message = f"{request.x} {request.y} {request.theta}"
        response.configurations = request.revolutions + 1
        return response

    def calibrate(self, request: Calibrate.Request, response: Calibrate.Response):
        response.success = not request.dry_run
        response.position_rms_before = 0.009
        response.position_rms_after = 0.002
        response.orientation_rms_before = 0.01
        response.orientation_rms_after = 0.002
        response.calibration_file = "" if request.dry_run else "/tmp/calibration.yaml"
        return response

    def list_configurations(self, request: ListConfigurations.Request, response: ListConfigurations.Response):
        response.configurations = 2
        response.summaries = ["0: a", "1: b"]
        response.dataset_file = "/tmp/dataset.yaml"
        return response


def main() -> None:
    rclpy.init()
    node = InterfaceEcho()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
