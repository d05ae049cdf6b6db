"""Bag fixtures shared by tests of several packages: bags written directly with rosbags."""
from __future__ import annotations

from pathlib import Path

from rosbags.rosbag2 import StoragePlugin, Writer

from soil_bag_tools.bag_io import META_KEY
from soil_msgs_py import messages
from soil_msgs_py.episode import Episode
from soil_msgs_py.messages import TYPESTORE
from soil_msgs_py.topics import EPISODE_TOPICS


def write_raw(bag: Path, ep: Episode, skip=lambda topic, i: False, replace=None, meta=True,
              namespaces: tuple[str, ...] = ("",)) -> Path:
    """A bag written directly with rosbags, to build the broken bags write_episode refuses to make;
    its topics under each of ``namespaces`` (as a machine's own recorder writes a namespaced graph's)."""
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        if meta:
            w.set_custom_data(META_KEY, ep.meta.to_json())
        conns = {t.name: [w.add_connection(ns + t.name, t.msgtype, typestore=TYPESTORE) for ns in namespaces]
                 for t in EPISODE_TOPICS if not skip(t.name, None)}
        for k, (topic, stamp, raw) in enumerate(messages.serialize_episode(ep)):
            i = k // len(EPISODE_TOPICS)
            if topic in conns and not skip(topic, i):
                if replace and (topic, i) == replace[0]:
                    raw = TYPESTORE.serialize_cdr(replace[1], replace[1].__msgtype__)
                for conn in conns[topic]:
                    w.write(conn, stamp, raw)
    return bag
