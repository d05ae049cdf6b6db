"""Column of each named value in a /soil/estimate vector and in a ground-truth row.

The live lines, the monitor, the bag scoring and the figure all index the same two vectors;
the names come from the message contract (soil_msgs_py), the indices are built here once.
"""
from soil_msgs_py import topics as T
from soil_msgs_py.params import GROUND_TRUTH_PARAMS

ESTIMATE_COLUMN = {name: i for i, name in enumerate(T.ESTIMATE_FIELDS)}
TRUTH_COLUMN = {name: i for i, name in enumerate(GROUND_TRUTH_PARAMS)}


def is_valid(estimate) -> bool:
    """An estimate vector flagged valid by the estimator (its window was full and finite)."""
    return bool(estimate[ESTIMATE_COLUMN["valid"]] > 0.5)
