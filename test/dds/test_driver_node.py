"""driver_node over DDS, as a separate process: the simulated sensor's bearings agree with the geometry
within their published variance, occluded beacons vanish, a missing serial device is a clear error."""

import math

import numpy as np
import pytest

from beams_common.geometry.beacon_map import EUROBOT_BEACON_MAP

WAIT_S = 20.0
STATIC_POSE = (1.0, 1.2, 0.4)


def true_bearing(beacon_id: int, pose: tuple[float, float, float]) -> float:
    bx, by = EUROBOT_BEACON_MAP.position(beacon_id)
    return math.atan2(by - pose[1], bx - pose[0]) - pose[2]


def collect_revolutions(rclpy_node, count: int) -> list:
    from rclpy.qos import qos_profile_sensor_data

    from beams_msgs.msg import BeaconBearingArray

    revolutions = rclpy_node.subscribe(BeaconBearingArray, "beams/bearings", qos_profile_sensor_data)
    assert rclpy_node.spin_until(lambda: len(revolutions) >= count, WAIT_S), f"{len(revolutions)} revolutions"
    return revolutions


def test_simulated_bearings_match_the_geometry_within_their_variance(rclpy_node, start_node):
    # The ideal model: unbiased bearings whose published variance is the simulated one (thesis_hardware
    # adds the uncalibrated 0.23 deg power bias of section 5.7 and a window-dependent natural noise).
    params = {"sim_static_pose": list(STATIC_POSE), "sim_noise_model": "ideal"}
    start_node("beams_driver", "driver_node", params=params)
    revolutions = collect_revolutions(rclpy_node, 30)
    normalised_errors = {1: [], 2: [], 3: []}
    for revolution in revolutions:
        assert revolution.header.frame_id == "beams_sensor"
        assert 0.0998 < revolution.period < 0.0999  # 62400 steps of a 625 kHz timer
        for bearing in revolution.bearings:
            error = math.remainder(
                bearing.bearing - true_bearing(bearing.beacon_id, STATIC_POSE), 2 * math.pi
            )
            assert -math.pi < bearing.bearing <= math.pi
            assert bearing.variance > 0.0 and bearing.angular_window > 0.0
            normalised_errors[bearing.beacon_id].append(error / math.sqrt(bearing.variance))
    for beacon_id, errors in normalised_errors.items():
        assert len(errors) >= 0.9 * len(revolutions), f"beacon {beacon_id} seen in {len(errors)} revolutions"
        # Normalised errors of an unbiased, correctly-weighted bearing: mean ~0, spread ~1.
        assert abs(np.mean(errors)) < 1.0, (beacon_id, np.mean(errors))
        assert 0.3 < np.std(errors) < 2.0, (beacon_id, np.std(errors))


def test_occluded_beacon_is_not_reported(rclpy_node, start_node):
    start_node(
        "beams_driver",
        "driver_node",
        params={"sim_static_pose": list(STATIC_POSE), "sim_occluded_beacons": [2]},
    )
    revolutions = collect_revolutions(rclpy_node, 10)
    seen = {bearing.beacon_id for revolution in revolutions for bearing in revolution.bearings}
    assert seen == {1, 3}


@pytest.mark.parametrize(
    ("params", "message"),
    [({"sim_noise_model": "perfect"}, "sim_noise_model"), ({"min_complete_codes": 0}, "min_complete_codes")],
)
def test_invalid_noise_model_or_code_count_is_a_clear_error(start_node, params, message):
    node = start_node("beams_driver", "driver_node", params=params)
    status = node.wait_exit(WAIT_S)
    output = node.log()
    assert status == 2, output
    assert message in output and "Traceback" not in output


def test_missing_serial_device_is_a_clear_error(start_node):
    node = start_node(
        "beams_driver", "driver_node", params={"source": "serial", "device": "/dev/beams_nowhere"}
    )
    status = node.wait_exit(WAIT_S)
    output = node.log()
    assert status == 2, output
    assert "/dev/beams_nowhere" in output and "does not exist" in output and "Traceback" not in output


def test_serial_source_through_a_pseudo_terminal(rclpy_node, start_node, tmp_path):
    """The simulator's edges, framed as the sensor's microcontroller sends them, over a real pty; corrupted
    bytes in the stream are counted and skipped, the bearings still agree with the geometry."""
    import os
    import threading
    import time

    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import qos_profile_sensor_data

    from beams_driver.serial_protocol import FrameEncoder
    from beams_msgs.msg import BeaconBearingArray
    from beams_sim.sensor_sim import SensorSimConfig, SensorSimulator

    master, slave = os.openpty()
    config = SensorSimConfig()
    simulator = SensorSimulator(config, EUROBOT_BEACON_MAP, np.random.default_rng(3))
    revolutions = [simulator.revolution(lambda t: STATIC_POSE, k * config.period_s) for k in range(60)]
    encoder = FrameEncoder()
    chunks = [encoder.revolution(edges) for edges in revolutions]
    chunks[20] = chunks[20][:5] + b"\x00\xff\x13garbage" + chunks[20][5:]
    stop = threading.Event()

    def device() -> None:
        for chunk in chunks:  # a real sensor streams one revolution every 0.1 s
            if stop.is_set():
                return
            os.write(master, chunk)
            time.sleep(config.period_s)

    rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    revolutions = rclpy_node.subscribe(BeaconBearingArray, "beams/bearings", qos_profile_sensor_data)
    node = start_node("beams_driver", "driver_node", params={"source": "serial", "device": os.ttyname(slave)})
    # the stream starts once the driver has opened the port (the pty raw) and the probe hears it: a pty's
    # line discipline mangles what comes before, and a backlog read at once is a burst the probe drops
    assert rclpy_node.spin_until(
        lambda: (
            "publishing /beams/bearings" in node.log() and rclpy_node.node.count_publishers("/beams/bearings")
        ),
        WAIT_S,
    ), node.log()
    writer = threading.Thread(target=device, daemon=True)
    writer.start()
    try:
        assert rclpy_node.spin_until(lambda: len(revolutions) >= 25, WAIT_S), (
            f"{len(revolutions)} revolutions"
        )
        received = revolutions
    finally:
        stop.set()
        writer.join(timeout=10)
    errors = [
        math.remainder(b.bearing - true_bearing(b.beacon_id, STATIC_POSE), 2 * math.pi)
        for revolution in received
        for b in revolution.bearings
    ]
    assert len(errors) >= 3 * 20
    assert np.sqrt(np.mean(np.square(errors))) < math.radians(0.2)

    def drops_reported() -> bool:
        values = rclpy_node.diagnostic_values("driver")
        return any(key.startswith("serial_drops_") and int(value) > 0 for key, value in values.items())

    assert rclpy_node.spin_until(drops_reported, WAIT_S), node.log()
    os.close(master)
    os.close(slave)


def test_reloaded_calibration_corrects_the_published_bearings(rclpy_node, start_node, tmp_path):
    """A calibration file written while the driver runs is applied on `~/reload_calibration` (issue 6);
    windows outside its power bias's fitted range are counted (bearings_power_bias_held)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from std_srvs.srv import Trigger

    from beams_common.calibration.bearing_correction import BearingCorrection
    from beams_common.calibration.calibration_file import SensorCalibration, save_calibration

    path = tmp_path / "calibration.yaml"
    save_calibration(SensorCalibration(beacon_map=EUROBOT_BEACON_MAP), path)
    start_node(
        "beams_driver",
        "driver_node",
        params={"sim_static_pose": list(STATIC_POSE), "calibration_file": str(path)},
    )

    def mean_error(revolutions) -> float:
        return float(
            np.mean(
                [
                    math.remainder(b.bearing - true_bearing(b.beacon_id, STATIC_POSE), 2 * math.pi)
                    for revolution in revolutions[-20:]
                    for b in revolution.bearings
                ]
            )
        )

    before = mean_error(collect_revolutions(rclpy_node, 20))
    constant_power_bias_rad = 0.01  # d, the constant of eq. 7.19's cubic: every bearing moves by -d
    # fitted on windows wider than the table's: held at its edge value, each bearing counted
    correction = BearingCorrection((0.0, 0.0, 0.0, constant_power_bias_rad), window_range_rad=(0.3, 0.4))
    save_calibration(SensorCalibration(beacon_map=EUROBOT_BEACON_MAP, bearing_correction=correction), path)
    reply = rclpy_node.call(Trigger, "/driver_node/reload_calibration", Trigger.Request(), WAIT_S)
    assert reply.success, reply.message
    rclpy_node.received.clear()
    rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    after = mean_error(collect_revolutions(rclpy_node, 20))
    assert after - before == pytest.approx(-constant_power_bias_rad, abs=0.002)
    held = lambda: int(rclpy_node.diagnostic_values("driver").get("bearings_power_bias_held", 0)) > 0  # noqa: E731
    assert rclpy_node.spin_until(held, WAIT_S), rclpy_node.diagnostic_values("driver")

    path.unlink()
    refused = rclpy_node.call(Trigger, "/driver_node/reload_calibration", Trigger.Request(), WAIT_S)
    assert not refused.success and "calibration.yaml" in refused.message


def test_driver_publishes_with_the_natural_variance_estimate_noise_writes(rclpy_node, start_node, tmp_path):
    """The parameter file estimate_noise writes, given after another `--params-file`: every published
    variance is the exact code variance at its window plus the window-dependent natural variance; a
    runtime change of the slope to 0 (ros2 param set) makes the natural part the constant again."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    from beams_driver.noise_estimation import NATURAL_REFERENCE_WINDOW, NATURAL_SLOPE, NATURAL_VARIANCE
    from beams_driver.parameters import DRIVER_PARAMETERS, codes_of, variance_model_of
    from beams_sim.sensor_sim import SensorSimConfig

    fitted = {NATURAL_VARIANCE: 9.7e-7, NATURAL_SLOPE: 1.0e-5, NATURAL_REFERENCE_WINDOW: 0.115}
    lines = ["/**/driver_node:", "  ros__parameters:"] + [f"    {k}: {v:.6e}" for k, v in fitted.items()]
    noise_file = tmp_path / "noise.yaml"
    noise_file.write_text("\n".join(lines) + "\n")
    start_node(
        "beams_driver",
        "driver_node",
        params={"sim_static_pose": list(STATIC_POSE)},
        extra_args=["--params-file", str(noise_file)],
    )
    values = {**DRIVER_PARAMETERS.defaults(), **fitted}
    codes = codes_of(values)
    receiver = SensorSimConfig.thesis_hardware(codes=codes)
    revolutions = collect_revolutions(rclpy_node, 5)
    for step, expected in enumerate((values, {**values, NATURAL_SLOPE: 0.0})):
        model = variance_model_of(expected, codes, receiver)
        # the revolutions published from now on (a change applies from the next revolution)
        first = len(revolutions) + 1
        assert rclpy_node.spin_until(lambda n=first: len(revolutions) >= n + 5, WAIT_S)
        published = [b for r in revolutions[first:] for b in r.bearings]
        assert len(published) >= 10
        for b in published:
            assert b.variance == pytest.approx(model.variance(b.beacon_id, b.angular_window), rel=1e-9), (
                step,
                b.beacon_id,
            )
        request = SetParameters.Request(parameters=[Parameter(NATURAL_SLOPE, value=0.0).to_parameter_msg()])
        results = rclpy_node.call(SetParameters, "/driver_node/set_parameters", request, WAIT_S).results
        assert results[0].successful, results[0].reason
