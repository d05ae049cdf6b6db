"""The README's topics table is the contract a user reads before subscribing: every topic the
graph's nodes make is in it with its message type, every labelled array's labels are named in
its row in their order, and the table names no topic the code does not make. Why: the contract
grew field by field (the fused soil, the planner's target) and a row that lags behind it sends a
user's planner to the wrong index of a Float64MultiArray."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from soil_msgs_py import graph as G
from soil_msgs_py import topics as T
from soil_msgs_py.markdown_table import cells_of

README = Path(__file__).resolve().parents[2] / "README.md"
STRING_TOPICS = (G.SIM_COMMAND_TOPIC, G.SIM_STATUS_TOPIC, G.SIM_EPISODE_TOPIC, G.ESTIMATOR_PHYSICS_TOPIC)


def topics_table() -> dict[str, list[str]]:
    """{topic: its row's cells} of the README's table under "## Topics"."""
    text = README.read_text(encoding="utf-8")
    section = text.split("\n## Topics\n", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        cells = cells_of(line) if line.startswith("| `/") else None
        if cells:
            rows[cells[0].strip("` ")] = cells
    return rows


def short_type(msgtype: str) -> str:
    """'geometry_msgs/msg/PointStamped' as the table writes it: 'geometry_msgs/PointStamped'."""
    package, _, name = msgtype.partition("/msg/")
    return f"{package}/{name}"


CONTRACT = {**{name: short_type(t.msgtype) for name, t in T.GRAPH_TOPICS_BY_NAME.items()},
            **{name: "std_msgs/String" for name in STRING_TOPICS}}


def test_the_table_names_exactly_the_graphs_topics():
    assert set(topics_table()) == set(G.GRAPH_OWN_TOPICS) == set(CONTRACT)


@pytest.mark.parametrize("name", sorted(CONTRACT))
def test_each_topics_row_gives_its_message_type(name):
    row = topics_table()[name]
    assert row[1].startswith(CONTRACT[name]), f"{name}: the README says {row[1]!r}, the code {CONTRACT[name]}"


@pytest.mark.parametrize("topic", [t for t in T.GRAPH_TOPICS_BY_NAME.values() if t.labels], ids=lambda t: t.name)
def test_each_labelled_arrays_row_names_its_labels_in_their_order(topic):
    fields = topics_table()[topic.name][-1]
    named = [label for label in topic.labels if f"`{label}`" in fields]
    missing = [label for label in topic.labels if label not in named]
    assert not missing, f"{topic.name}: the README's fields lack {missing}"
    said = iter(re.findall(r"`([^`]+)`", fields))  # (a label may be named again in another's explanation)
    assert all(label in said for label in topic.labels), \
        f"{topic.name}: the README names the labels in another order than the message's {topic.labels}"


def test_the_maps_row_names_its_point_fields():
    fields = topics_table()[T.SOIL_MAP.name][-1]
    assert [f for f in T.MAP_FIELDS if not re.search(rf"`{f}`", fields)] == []
