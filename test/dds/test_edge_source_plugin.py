"""A new edge source is a new module, not an edit to the driver: driver_node runs a replay of recorded
edges from a package outside the project (test/plugins), chosen by its `source` parameter, and publishes
bearings that agree with the recording's geometry."""

import math
import os
import pathlib

import numpy as np

PLUGINS = pathlib.Path(__file__).resolve().parent / "plugins"
STATIC_POSE = (1.2, 0.8, 0.3)
WAIT_S = 20.0


def _true_bearing(beacon_xy, pose) -> float:
    return math.atan2(beacon_xy[1] - pose[1], beacon_xy[0] - pose[0]) - pose[2]


def test_a_replay_source_from_another_package_plugs_into_the_driver(
    rclpy_node, start_node, ros_env, tmp_path, monkeypatch
):
    from rclpy.qos import qos_profile_sensor_data

    from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP
    from beams_msgs.msg import BeaconBearingArray
    from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator

    monkeypatch.syspath_prepend(str(PLUGINS))
    from beams_test_plugins.replay_source import save_recording

    config = SensorSimConfig()
    simulator = SensorSimulator(config, EUROBOT_BEACON_MAP, np.random.default_rng(5))
    recording = tmp_path / "edges.npz"
    save_recording(
        str(recording), [simulator.revolution(lambda t: STATIC_POSE, k * config.period_s) for k in range(20)]
    )

    ros_env["PYTHONPATH"] = f"{PLUGINS}{os.pathsep}{ros_env.get('PYTHONPATH', '')}"  # the node's environment
    start_node(
        "beams_driver",
        "driver_node",
        {"source": "beams_test_plugins.replay_source:EDGE_SOURCE", "replay_file": str(recording)},
    )
    revolutions = rclpy_node.subscribe(BeaconBearingArray, "beams/bearings", qos_profile_sensor_data)
    assert rclpy_node.spin_until(lambda: len(revolutions) >= 30, WAIT_S), f"{len(revolutions)} revolutions"
    beacons = EUROBOT_BEACON_MAP.as_dict()
    normalised = [
        math.remainder(b.bearing - _true_bearing(beacons[b.beacon_id], STATIC_POSE), 2 * math.pi)
        / math.sqrt(b.variance)
        for revolution in revolutions[1:]
        for b in revolution.bearings
    ]
    assert len(normalised) >= 3 * 25
    # the replayed bearings are the simulator's: their spread is what their published variance says
    assert 0.5 < float(np.std(normalised)) < 2.0 and abs(float(np.mean(normalised))) < 1.0


def test_an_unknown_source_is_one_line_and_exit_2(start_node):
    node = start_node("beams_driver", "driver_node", {"source": "no_such_package.module:EDGE_SOURCE"})
    assert node.wait_exit(WAIT_S) == 2
    assert "source 'no_such_package.module:EDGE_SOURCE'" in node.log() and "Traceback" not in node.log()
