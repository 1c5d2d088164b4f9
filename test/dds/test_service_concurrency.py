"""Every service of every node answers 20 concurrent calls: each node's console script started (each in a
namespace of its own), its services read from the graph (its own, the parameter services, the lifecycle
and type-description ones rcl creates), 20 calls fired at once at each from several clients with the
default request; all 20 are answered within a bounded wait, each reply meaningful (a refusal with its
reason), and the node still publishes /diagnostics after.

Every client of a service receives the replies to all of them (rmw_fastrtps filters them on take): the
clients here keep as many replies as the burst has (CLIENT_QOS), as one operator's client with its own
calls does. The services keep their requests and replies by the Fast DDS profile's `service` entries
(beams_bringup's fastdds_fast_discovery.xml, exported by scripts/ros_env.sh) and, without it, by the
QoS of the services the nodes create (callback_guard.SERVICES_QOS, rclpy's parameter services)."""

import ast
import importlib
import pathlib
import time

from rclpy.qos import QoSProfile

SRC = pathlib.Path(__file__).resolve().parents[2] / "src"
CALLS = 20
CLIENTS = 4
CLIENT_QOS = QoSProfile(depth=CALLS)
UP_TIMEOUT_S = 30.0
# a burst's answers come within 0.3 s; capture_reference without a driver answers its first call when its
# wait for the default request's revolutions ends (10 here: 7 s), the other 19 at once (busy)
ANSWER_TIMEOUT_S = 30.0
# what a node needs to start on its own (the rest are its defaults); the calibration node's default request
# waits for 100 revolutions (25 s without a driver): 10 keep the wait of one burst short
PARAMS = {
    "driver_node": {"sim_static_pose": [1.5, 1.0, 0.0]},
    "calibration_node": {"default_revolutions": 10},
}


def _nodes() -> list[tuple[str, str]]:
    """(package, executable) of every node's console script."""
    nodes = []
    for setup in sorted(SRC.glob("*/setup.py")):
        for node in ast.walk(ast.parse(setup.read_text())):
            if isinstance(node, ast.keyword) and node.arg == "entry_points":
                for entry in ast.literal_eval(node.value).get("console_scripts", []):
                    name = entry.split("=")[0].strip()
                    nodes += [(setup.parent.name, name)] if name.endswith("_node") else []
    return nodes


def _service_type(name: str):
    """The class of a service type named as the graph names it ("std_srvs/srv/Trigger")."""
    package, kind, type_name = name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), type_name)


def _meaningless(reply) -> str:
    """Why a reply says nothing, or '': a refusal (success false) must say why when it has a message."""
    if reply is None:
        return "no reply"
    if getattr(reply, "success", True) is False and hasattr(reply, "message") and not reply.message:
        return "refused without a reason"
    return ""


def test_every_service_answers_a_burst_of_20_concurrent_calls(rclpy_node, start_node, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray

    diagnostics = rclpy_node.subscribe(DiagnosticArray, "/diagnostics")
    started = {}
    for k, (package, executable) in enumerate(_nodes()):
        params = dict(PARAMS.get(executable, {}))
        if executable == "calibration_node":
            params["dataset_file"] = str(tmp_path / "dataset.yaml")
        if executable == "ekf_node":  # save_calibration writes it (default: the working directory)
            params["self_calibration_file"] = str(tmp_path / "self_calibration.yaml")
        started[f"/n{k}"] = (executable, start_node(package, executable, params or None, namespace=f"n{k}"))
    graph = rclpy_node.node

    def services_of(namespace: str, executable: str) -> list[tuple[str, str]]:
        try:
            found = graph.get_service_names_and_types_by_node(executable, namespace)
        except Exception:  # not discovered yet
            return []
        return [(name, types[0]) for name, types in found]

    def all_up() -> bool:
        return all(services_of(ns, exe) for ns, (exe, _) in started.items())

    logs = "\n".join(node.log() for _, node in started.values())
    assert rclpy_node.spin_until(all_up, UP_TIMEOUT_S), logs
    rclpy_node.spin_for(1.0)  # the rest of each node's services
    failures = []
    for namespace, (executable, node) in started.items():
        for service, type_name in sorted(services_of(namespace, executable)):
            srv_type = _service_type(type_name)
            clients = [graph.create_client(srv_type, service, qos_profile=CLIENT_QOS) for _ in range(CLIENTS)]
            if not all(c.wait_for_service(timeout_sec=UP_TIMEOUT_S) for c in clients):
                failures.append(f"{service}: not available")
                continue
            futures = [clients[k % CLIENTS].call_async(srv_type.Request()) for k in range(CALLS)]
            start = time.monotonic()
            rclpy_node.spin_until(lambda fs=futures: all(f.done() for f in fs), ANSWER_TIMEOUT_S)
            answered = [f.result() for f in futures if f.done()]
            problems = {_meaningless(r) for r in answered} - {""}
            if len(answered) < CALLS or problems:
                failures.append(f"{service}: {len(answered)}/{CALLS} answered {sorted(problems)}")
                assert not failures, failures  # the first failing service: no need to wait for the others
            print(
                f"{service}: {len(answered)}/{CALLS} answered in {time.monotonic() - start:.2f} s", flush=True
            )
            for client in clients:
                graph.destroy_client(client)
        count = len(diagnostics)

        def published_again(ns=namespace, count=count) -> bool:
            return any(f"{ns}/" in s.name for m in diagnostics[count:] for s in m.status)

        publishes = any(f"{namespace}/" in s.name for m in diagnostics[:count] for s in m.status)
        if publishes and not rclpy_node.spin_until(published_again, 10.0):  # fault_relay_node has none
            failures.append(
                f"{namespace} ({executable}): no /diagnostics after the calls\n{node.log()[-2000:]}"
            )
    assert not failures, "\n".join(failures)
