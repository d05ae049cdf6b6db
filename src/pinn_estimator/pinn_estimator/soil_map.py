"""The fused soil along the path, cell by cell (no rclpy): what ``/soil/map`` carries.

The estimator's posterior is the soil at the blade now; a planner of later passes wants it
where it was learnt. Each cell of ``cell_m`` of blade-edge travel in x keeps the posterior as
it stood after the last stretch that ended with the edge in the cell, with the cut floor's
height z there. Rows are in ``topics.MAP_FIELDS`` order (x, y = 0, z, φ, c, δ and their
standard deviations, SI), sorted by x; the node packs them into a PointCloud2 (float32) that
Foxglove draws in the world frame.
"""
from __future__ import annotations

import math

import numpy as np

from soil_msgs_py.topics import MAP_FIELDS

CELL_M = 0.5  # cell length along x [m]: about one stretch of cutting at the controller's speeds
MAX_CELLS = 4000  # 2 km of path; beyond that the cells updated longest ago are dropped


class SoilMap:
    def __init__(self, cell_m: float = CELL_M, max_cells: int = MAX_CELLS):
        if not (math.isfinite(cell_m) and cell_m > 0):
            raise ValueError(f"soil map cell_m={cell_m!r} must be a positive length [m]")
        self.cell_m = cell_m
        self.max_cells = max_cells
        self.cells: dict[int, np.ndarray] = {}  # cell index -> row (MAP_FIELDS); insertion = update order

    def clear(self) -> None:
        self.cells.clear()

    def add(self, x_m: float, z_m: float, summary) -> bool:
        """The posterior ``summary`` (``fusion.Summary``) at blade edge (x, z) [m]; False if not finite."""
        values = [x_m, 0.0, z_m, summary.mean["phi"], summary.mean["c"], summary.mean["delta"],
                  summary.std["phi"], summary.std["c"], summary.std["delta"]]
        row = np.array(values, dtype=float)
        if not np.isfinite(row).all():
            return False
        key = math.floor(x_m / self.cell_m)
        row[0] = (key + 0.5) * self.cell_m  # the cell's centre
        self.cells.pop(key, None)
        self.cells[key] = row
        while len(self.cells) > self.max_cells:
            self.cells.pop(next(iter(self.cells)))
        return True

    def rows(self) -> np.ndarray:
        """(n, len(MAP_FIELDS)) rows sorted by x."""
        if not self.cells:
            return np.zeros((0, len(MAP_FIELDS)))
        return np.stack([self.cells[k] for k in sorted(self.cells)])
