"""Estimates with known errors and episode bags that carry them, as the recorder writes them."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from soil_bag_tools.bag_io import META_KEY
from soil_msgs_py import messages as M
from soil_msgs_py import topics as T
from soil_msgs_py.params import DEG

from soil_bringup.estimate_columns import ESTIMATE_COLUMN as EST
from soil_bringup.estimate_columns import TRUTH_COLUMN as TRUTH


def estimate(ep, row: int, valid: bool, window: int, offsets=(2 * DEG, 500.0, -1 * DEG, 3 * DEG),
             f_off=(100.0, -200.0)) -> np.ndarray:
    """An estimate vector for tick ``row``: the truth plus ``offsets`` (φ, c, δ, β), the force plus ``f_off``."""
    values = np.zeros(len(T.ESTIMATE_FIELDS))
    values[EST["window_samples"]] = window
    if valid:
        for name, off in zip(("phi", "c", "delta", "beta"), offsets):
            values[EST[name]] = ep.truth[row, TRUTH[name]] + off
        values[EST["f_x_hat"]] = ep.forces[row, 0] + f_off[0]
        values[EST["f_z_hat"]] = ep.forces[row, 1] + f_off[1]
        values[EST["valid"]] = 1.0
    return values


def write_bag_with_estimates(path: Path, ep, estimates: list[tuple[int, np.ndarray]], labels=T.ESTIMATE_FIELDS) -> Path:
    """An episode bag like the recorder's: the episode topics plus /soil/estimate (in the layout of
    ``labels``: an older one's, each estimate's values of those fields)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        writer.set_custom_data(META_KEY, ep.meta.to_json())
        conns = {t.name: writer.add_connection(t.name, t.msgtype, typestore=M.TYPESTORE)
                 for t in (*T.EPISODE_TOPICS, T.ESTIMATE)}
        for topic, stamp, raw in M.serialize_episode(ep, M.TYPESTORE):
            writer.write(conns[topic], stamp, raw)
        for stamp, values in estimates:
            values = [values[T.ESTIMATE_FIELDS.index(name)] for name in labels]
            msg = M.make_labelled(M.TYPESTORE, stamp, labels, values)
            writer.write(conns[T.ESTIMATE.name], stamp, M.TYPESTORE.serialize_cdr(msg, T.ESTIMATE.msgtype))
    return path
