"""The demo's live console lines (soil_bringup.live_lines): layout and what they say."""
from __future__ import annotations

import numpy as np

from soil_msgs_py.params import DEG

from soil_bringup import live_lines
from soil_bringup.estimate_columns import ESTIMATE_COLUMN as EST
from soil_bringup.estimate_columns import TRUTH_COLUMN as TRUTH
from tests.soil_bringup.estimate_bags import estimate


def test_live_lines_fit_120_columns_and_say_when_the_window_fills(episode):
    truth = episode.truth[70]
    force = np.array([-19_999.0, 29_999.0])
    valid = estimate(episode, 70, True, 60)
    valid[EST["c"]] = 99_999.0  # wide numbers must not break the layout
    lines = [*live_lines.header_lines(), live_lines.estimate_line("Gravel", 100.0, 59.0, valid, truth, force),
             live_lines.estimate_line("Clay", 20.0, 0.5, estimate(episode, 29, False, 30), truth, force),
             live_lines.estimate_line("Sand", 0.0, 3.0, None, None, None, note="no estimate received")]
    assert all(len(line) <= 120 for line in lines), [len(x) for x in lines]
    assert "filling window 30/60" in lines[3] and "--/" in lines[3]
    assert f"{truth[TRUTH['phi']] / DEG:.1f}" in lines[2]


def test_a_soil_name_longer_than_its_column_is_cut_visibly_not_into_another_soils_name():
    """A user's "GravellySand" cut to six characters read "Gravel", a catalogue soil of its own."""
    prefixes = [live_lines.line_prefix(name, 50.0, 1.0) for name in ("GravellySand", "Gravel", "SiltyClay")]
    assert prefixes[0].startswith("Grave… ") and prefixes[1].startswith("Gravel ") and prefixes[2].startswith("Silty… ")
    assert {len(p) for p in prefixes} == {live_lines.PREFIX_WIDTH}
