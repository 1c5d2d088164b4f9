"""Read and write rosbag2 bags (MCAP or sqlite3) of the BeAMS topics without a ROS install (`rosbags`): CDR
bytes as they travelled over DDS, topics fully qualified, each with its publishers' offered QoS profiles, as
`ros2 bag record` writes them, so that `ros2 bag play` replays them unchanged."""

import pathlib
from collections.abc import Iterable, Iterator, Sequence
from types import TracebackType
from typing import Any

from ament_index_python.packages import get_package_share_directory
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

BEAMS_MSGS_PACKAGE = "beams_msgs"
# rmw's infinite duration (RMW_DURATION_INFINITE), as rosbag2 writes it for "no deadline" and the like
INFINITE_DURATION = QosTime(sec=9_223_372_036, nsec=854_775_807)


def offered_qos(depth: int = 10, *, reliable: bool = True, transient_local: bool = False) -> Qos:
    """A publisher's profile as offered_qos_profiles holds it: keep last `depth`, automatic liveliness,
    no deadline or lifespan (what the BeAMS nodes publish with: reliable, volatile, depth 10)."""
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=depth,
        reliability=QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
        durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
        deadline=INFINITE_DURATION,
        lifespan=INFINITE_DURATION,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=INFINITE_DURATION,
        avoid_ros_namespace_conventions=False,
    )


def fully_qualified(topic: str) -> str:
    """The topic name as `ros2 bag record` writes it, from the root namespace: "odom" is "/odom"."""
    return "/" + topic.lstrip("/")


def beams_typestore(beams_msgs_share: pathlib.Path | None = None) -> Typestore:
    """The ROS 2 Jazzy typestore extended with the beams_msgs message definitions."""
    share = beams_msgs_share or pathlib.Path(get_package_share_directory(BEAMS_MSGS_PACKAGE))
    typestore = get_typestore(Stores.ROS2_JAZZY)
    definitions: dict[str, Any] = {}
    for msg_file in sorted((share / "msg").glob("*.msg")):
        definitions.update(
            get_types_from_msg(msg_file.read_text(), f"{BEAMS_MSGS_PACKAGE}/msg/{msg_file.stem}")
        )
    typestore.register(definitions)
    return typestore


class BagRecorder:
    """Write serialized messages to a new bag; one connection per topic, created on first use."""

    def __init__(self, path: pathlib.Path, typestore: Typestore, storage: str = "mcap") -> None:
        if path.exists():
            raise FileExistsError(f"bag {path} exists already; choose another output directory")
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        self._writer = Writer(path, version=9, storage_plugin=plugin)
        self._typestore = typestore
        self._connections: dict[str, Any] = {}
        self.messages_written = 0

    def __enter__(self) -> "BagRecorder":
        self._writer.open()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: TracebackType | None
    ) -> None:
        self._writer.close()

    def write(
        self, topic: str, msgtype: str, stamp_ns: int, cdr_bytes: bytes, offered_qos: Sequence[Qos] = ()
    ) -> None:
        """Append one message (ROS type name such as 'nav_msgs/msg/Odometry') received at stamp_ns; the
        topic's first message records its publishers' offered_qos in the bag's metadata."""
        connection = self._connections.get(topic)
        if connection is None:
            connection = self._writer.add_connection(
                topic, msgtype, typestore=self._typestore, offered_qos_profiles=list(offered_qos)
            )
            self._connections[topic] = connection
        self._writer.write(connection, stamp_ns, cdr_bytes)
        self.messages_written += 1


def read_messages(
    path: pathlib.Path, typestore: Typestore, topics: Iterable[str] | None = None
) -> Iterator[tuple[str, int, Any]]:
    """Yield (topic, bag timestamp ns, deserialized message) in bag order, for sqlite3 and MCAP bags."""
    wanted = set(topics) if topics is not None else None
    with Reader(path) as reader:
        connections = [c for c in reader.connections if wanted is None or c.topic in wanted]
        for connection, timestamp, raw in reader.messages(connections=connections):
            yield connection.topic, timestamp, typestore.deserialize_cdr(raw, connection.msgtype)
