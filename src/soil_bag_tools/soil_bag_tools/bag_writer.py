"""The one way the project writes a rosbag2 bag: rosbags' Writer with an MCAP storage that
carries its integrity.

rosbags' Writer (0.11.9) writes metadata.yaml the way rosbag2 Jazzy does (bag version 9,
``offered_qos_profiles`` as a list per topic, ``type_description_hash``), but its own MCAP
storage stores every CRC as 0 ("not computed") and no ``topic_type_hash`` channel metadata.
:class:`BagWriter` swaps in :class:`CrcMcapStorage`, which writes the ``.mcap`` with the
``mcap`` library's Writer instead: chunk CRCs, the data-section CRC and the summary CRC are
computed, and each channel carries the ``offered_qos_profiles``/``topic_type_hash``
metadata rosbag2's MCAP plugin writes, so a bag moved between machines can be checked
(``integrity.py``) and ``ros2 bag play`` offers the QoS the publishers offered. Nothing
time-dependent goes in: the same input gives the same bytes.
"""
from __future__ import annotations

from importlib.metadata import version
from pathlib import Path
from typing import cast

from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import (
    Connection, ConnectionExtRosbag2, MessageDefinitionFormat, Qos, QosDurability, QosHistory,
    QosLiveliness, QosReliability, QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionMode

from soil_msgs_py.graph import QosSpec, publisher_qos_spec

# Chunks are the unit a damaged bag loses: small enough that a flipped block costs ~1 s of a
# 60 Hz episode (~75 kB/s), large enough that the index stays a small part of the file.
CHUNK_SIZE_BYTES = 64 * 1024
LIBRARY = f"insitu-soil (mcap {version('mcap')}, rosbags {version('rosbags')})"


def rosbags_qos(spec: QosSpec) -> Qos:
    """graph.QosSpec as the rosbags Qos a bag stores in ``offered_qos_profiles``."""
    zero = QosTime(0, 0)  # ROS 2's "default" deadline/lifespan/lease: none
    return Qos(
        QosHistory.KEEP_LAST, spec.depth, QosReliability[spec.reliability.upper()],
        QosDurability[spec.durability.upper()], zero, zero, QosLiveliness.AUTOMATIC, zero, False,
    )


def offered_qos(topic: str) -> list[Qos]:
    """What the live graph's publishers offer on ``topic``, as a bag's ``offered_qos_profiles``."""
    return [rosbags_qos(publisher_qos_spec(topic))]


class CrcMcapStorage:
    """rosbags' storage-writer protocol on top of the ``mcap`` library's Writer."""

    def __init__(self, path: Path, compression: CompressionMode) -> None:
        if compression != CompressionMode.NONE:
            raise ValueError(f"compression mode {compression.name} is not supported by {type(self).__name__}")
        self.path = path / f"{path.name}.mcap"
        self._file = self.path.open("xb")
        self._mcap = McapWriter(self._file, chunk_size=CHUNK_SIZE_BYTES, compression=CompressionType.NONE,
                                enable_crcs=True, enable_data_crcs=True)
        self._mcap.start(profile="ros2", library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[int, int] = {}  # rosbags connection id -> MCAP channel id

    def add_msgtype(self, connection: Connection) -> None:
        fmt = "ros2msg" if connection.msgdef.format == MessageDefinitionFormat.MSG else "ros2idl"
        self._schemas[connection.msgtype] = self._mcap.register_schema(
            connection.msgtype, fmt, connection.msgdef.data.encode())

    def add_connection(self, connection: Connection, offered_qos_profiles: str) -> None:
        ext = cast(ConnectionExtRosbag2, connection.ext)
        self._channels[connection.id] = self._mcap.register_channel(
            connection.topic, ext.serialization_format, self._schemas[connection.msgtype],
            {"offered_qos_profiles": offered_qos_profiles, "topic_type_hash": connection.digest},
        )

    def write(self, connection: Connection, timestamp: int, data: bytes | memoryview) -> None:
        self._mcap.add_message(self._channels[connection.id], timestamp, bytes(data), timestamp)

    def close(self, version: int, metadata: str) -> None:  # noqa: ARG002 - the protocol's signature
        """Footer, summary and rosbag2's own copy of metadata.yaml (a Metadata record)."""
        try:
            self._mcap.add_metadata("rosbag2", {"serialized_metadata": metadata})
            self._mcap.finish()
        finally:
            self._file.close()

    def abort(self) -> None:
        self._file.close()


class BagWriter(Writer):
    """rosbags' Writer, bag version 9, MCAP written by :class:`CrcMcapStorage`."""

    STORAGE_PLUGINS = {StoragePlugin.MCAP: CrcMcapStorage}

    def __init__(self, path: Path | str) -> None:
        super().__init__(path, version=9, storage_plugin=StoragePlugin.MCAP)
