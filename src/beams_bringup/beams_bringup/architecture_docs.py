"""The README's picture of the nodes, topics, services and TF frames, written from the nodes themselves.

    python -m beams_bringup.architecture_docs                    # print the Mermaid diagrams
    python -m beams_bringup.architecture_docs --write README.md  # replace the block between the markers

Each node of the robot (beams_tools.robot_processes.ROBOT_NODES) and the calibration node is created
in this process with its default parameters, and asked what it publishes, subscribes to and serves (the
ROS graph of its own participant: nothing is declared twice); the frames are the nodes' frame parameters.
The picture sits in README.md between `<!-- architecture -->` and `<!-- /architecture -->`;
test/static/test_docs_in_sync.py fails when it differs from what this module writes. Run it in a
ROS_DOMAIN_ID of its own (the test claims one): nodes of the same names elsewhere in the domain would
show in the graph.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import pathlib
import re
import sys
from dataclasses import dataclass, field

from beams_common.interfaces import topics
from beams_tools.robot_processes import ROBOT_NODES, RobotNode

# Started by hand while calibrating (README, docs/calibration.md), not by the launch file.
HAND_STARTED = (RobotNode("beams_calibration", "calibration_node"),)
# Which transform each /tf publisher sends: (parent, child) frame parameters of that node. A node that
# publishes /tf without an entry here stops the generator (say which transform it sends).
TF_TRANSFORMS = {"ekf_node": ("map_frame", "odom_frame"), "sim_world_node": ("odom_frame", "base_frame")}
# The sensor frame: the bearings' frame_id, at turret_offset_m in the robot's frame (not on /tf).
SENSOR_FRAME = ("driver_node", "frame_id")
ROBOT_FRAME = ("ekf_node", "base_frame")
# Every node has these; the picture leaves them out (ROS's own, or said once under the picture).
_COMMON_TOPICS = {"/parameter_events", "/rosout", topics.DIAGNOSTICS}
_COMMON_SERVICE = re.compile(
    r"/(describe_parameters|get_parameters|get_parameter_types|list_parameters|"
    r"set_parameters|set_parameters_atomically|get_type_description)$"
)
_LIFECYCLE_SERVICE = re.compile(
    r"/(change_state|get_state|get_available_states|get_available_transitions|"
    r"get_transition_graph)$"
)
GENERATED = "written by python -m beams_bringup.architecture_docs --write README.md: do not edit"
_BLOCK = re.compile(r"(<!-- architecture -->\n)(?P<body>.*?)(<!-- /architecture -->)", re.S)


@dataclass
class NodeFacts:
    """What one node declares in the ROS graph, by the names the README uses."""

    package: str
    name: str
    simulation_only: bool
    hand_started: bool
    publishes: dict[str, str] = field(default_factory=dict)  # topic -> type
    subscribes: dict[str, str] = field(default_factory=dict)
    services: list[str] = field(default_factory=list)
    lifecycle: bool = False
    frames: dict[str, str] = field(default_factory=dict)  # frame parameter -> default


def _readme_name(resolved: str) -> str:
    """`/beams/bearings` as the README names it (`beams/bearings`, relative: a namespace applies);
    ROS-wide names keep their slash; a private service is `~/name`."""
    relative = {
        "/" + value: value
        for name, value in vars(topics).items()
        if name.isupper() and isinstance(value, str)
    }
    return relative.get(resolved, resolved)


def _short_type(full: str) -> str:
    return full.replace("/msg/", "/").replace("/srv/", "/")


def _node_class(robot_node: RobotNode) -> type:
    from rclpy.node import Node

    module = importlib.import_module(f"{robot_node.package}.{robot_node.executable}")
    classes = [
        value
        for value in vars(module).values()
        if inspect.isclass(value) and issubclass(value, Node) and value.__module__ == module.__name__
    ]
    if len(classes) != 1:
        raise LookupError(f"{module.__name__} defines {len(classes)} node classes; expected one")
    return classes[0]


def collect() -> list[NodeFacts]:
    """Create every node (defaults), read its endpoints from the graph, destroy it."""
    import rclpy

    rclpy.init(args=[])
    facts = []
    try:
        for robot_node in (*ROBOT_NODES, *HAND_STARTED):
            node = _node_class(robot_node)()
            name, namespace = node.get_name(), node.get_namespace()
            fact = NodeFacts(robot_node.package, name, robot_node.simulation_only, robot_node in HAND_STARTED)
            for topic, types in node.get_publisher_names_and_types_by_node(name, namespace):
                if topic not in _COMMON_TOPICS and not topic.endswith("/transition_event"):
                    fact.publishes[_readme_name(topic)] = _short_type(types[0])
            for topic, types in node.get_subscriber_names_and_types_by_node(name, namespace):
                fact.subscribes[_readme_name(topic)] = _short_type(types[0])
            for service, _types in node.get_service_names_and_types_by_node(name, namespace):
                if _LIFECYCLE_SERVICE.search(service):
                    fact.lifecycle = True
                elif not _COMMON_SERVICE.search(service):
                    fact.services.append(service.replace(f"{namespace.rstrip('/')}/{name}/", "~/"))
            fact.services.sort()
            parameters = [*TF_TRANSFORMS.get(name, ())]
            parameters += [p for n, p in (SENSOR_FRAME, ROBOT_FRAME) if n == name]
            fact.frames = {p: node.get_parameter(p).value for p in parameters}
            if (topics.TF in fact.publishes) != (name in TF_TRANSFORMS):
                raise LookupError(
                    f"{name}: publishes /tf is {topics.TF in fact.publishes}; update TF_TRANSFORMS"
                )
            facts.append(fact)
            node.destroy_node()
    finally:
        rclpy.shutdown()
    return facts


def _id(text: str) -> str:
    return re.sub(r"\W", "_", text.strip("/~")) or "root"


def mermaid(facts: list[NodeFacts]) -> str:
    """Two Mermaid diagrams (nodes and topics; TF frames) and the line said of every node."""
    lines = ["```mermaid", "flowchart LR", f"    %% {GENERATED}"]
    for fact in facts:
        notes = [fact.package]
        notes += ["simulation only"] if fact.simulation_only else []
        notes += ["started by hand"] if fact.hand_started else []
        notes += ["lifecycle node"] if fact.lifecycle else []
        label = f"<b>{fact.name}</b><br/><i>{' · '.join(notes)}</i>"
        label += "".join(f"<br/>{service}" for service in fact.services)
        lines.append(f'    {fact.name}["{label}"]')
    all_topics: dict[str, str] = {}
    for fact in facts:
        all_topics.update(fact.publishes)
        all_topics.update(fact.subscribes)
    for topic, msg_type in sorted(all_topics.items()):
        lines.append(f'    t_{_id(topic)}(["{topic}<br/><i>{msg_type}</i>"])')
    for fact in facts:
        lines += [f"    {fact.name} --> t_{_id(topic)}" for topic in sorted(fact.publishes)]
    for fact in facts:
        lines += [f"    t_{_id(topic)} --> {fact.name}" for topic in sorted(fact.subscribes)]
    dashed = [fact.name for fact in facts if fact.simulation_only or fact.hand_started]
    lines += [
        "    classDef optional stroke-dasharray: 5 5",
        f"    class {','.join(dashed)} optional",
        "```",
        "",
    ]

    by_name = {fact.name: fact for fact in facts}
    lines += ["```mermaid", "flowchart TB", f"    %% {GENERATED}"]
    for name, (parent, child) in TF_TRANSFORMS.items():
        frames = by_name[name].frames
        lines.append(
            f'    f_{_id(frames[parent])}(("{frames[parent]}")) -->|"{name}, /tf"| '
            f'f_{_id(frames[child])}(("{frames[child]}"))'
        )
    robot = by_name[ROBOT_FRAME[0]].frames[ROBOT_FRAME[1]]
    sensor = by_name[SENSOR_FRAME[0]].frames[SENSOR_FRAME[1]]
    lines += [
        f'    f_{_id(robot)} -.->|"turret_offset_m (not on /tf)"| f_{_id(sensor)}(("{sensor}"))',
        "```",
        "",
    ]
    return "\n".join(lines)


def write(readme: str, picture: str) -> str:
    """The README with the picture written anew between its markers."""
    if not _BLOCK.search(readme):
        raise KeyError("the README has no <!-- architecture --> block")
    return _BLOCK.sub(lambda match: match.group(1) + picture + match.group(3), readme)


def picture_in(readme: str) -> str | None:
    match = _BLOCK.search(readme)
    return match.group("body") if match else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", type=pathlib.Path, help="README to update in place")
    options = parser.parse_args(argv)
    picture = mermaid(collect())
    if options.write:
        options.write.write_text(write(options.write.read_text(), picture))
    else:
        print(picture, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
