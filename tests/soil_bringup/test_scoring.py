"""Scoring a recorded episode bag (soil_bringup.scoring) against a bag with known errors."""
from __future__ import annotations

import numpy as np
import pytest

from soil_bag_tools.bag_io import write_episode
from soil_msgs_py.params import DEG

from soil_bringup import scoring as S
from soil_bringup.estimate_columns import ESTIMATE_COLUMN as EST
from soil_bringup.estimate_columns import TRUTH_COLUMN as TRUTH
from soil_bringup.summary import table_text
from tests.soil_bringup.estimate_bags import estimate, write_bag_with_estimates


def test_summarise_matches_valid_estimates_to_ticks_and_scores_them(tmp_path, episode):
    ep = episode
    stamps = ep.stamps_ns
    estimates = [(int(stamps[k]), estimate(ep, k, False, k + 1)) for k in range(59)]  # window filling
    valid_rows = [k for k in range(59, len(ep)) if not 80 <= k < 90]  # 10 ticks without an estimate
    estimates += [(int(stamps[k]), estimate(ep, k, True, 60)) for k in valid_rows]
    wild = estimate(ep, 100, True, 60, offsets=(40 * DEG, 9e3, 40 * DEG, 40 * DEG), f_off=(9e3, 9e3))
    estimates.append((int(stamps[100]), wild))  # a second estimate for tick 100: the first one counts
    estimates.append((int(stamps[100]) + 1, wild))  # not on a tick: ignored
    bag = write_bag_with_estimates(tmp_path / ep.meta.name, ep, estimates)

    s = S.summarise(bag)
    assert s["ticks"] == len(ep) == 120 and s["estimates"] == len(estimates)
    assert s["valid_estimates"] == len(valid_rows) == 51
    assert s["duplicate_valid"] == 1 and s["valid_off_tick"] == 1
    assert s["pct_ticks_valid"] == pytest.approx(100 * 51 / 120)
    assert s["pct_full_window_ticks_valid"] == pytest.approx(100 * 51 / 61)
    assert s["first_valid_s"] == pytest.approx(59 / 60, abs=1e-6)
    assert s["soil"] == "Clay" and s["relative_density_pct"] == 20.0
    p, f = s["params"], s["force"]
    assert p["phi_mae_deg"] == pytest.approx(2.0) and p["c_mae_kPa"] == pytest.approx(0.5)
    assert p["delta_mae_deg"] == pytest.approx(1.0) and p["beta_mae_deg"] == pytest.approx(3.0)
    assert f["mae_x_n"] == pytest.approx(100.0) and f["mae_z_n"] == pytest.approx(200.0)
    assert f["windows"] == 51
    rows = np.array(valid_rows)
    assert f["mae_x_pct_measured"] == pytest.approx(100 * 100.0 / np.abs(ep.forces[rows, 0]).mean())
    assert s["truth_mean"]["phi_deg"] == pytest.approx(ep.truth[rows, TRUTH["phi"]].mean() / DEG)
    assert s["estimate_mean"]["phi_deg"] == pytest.approx(s["truth_mean"]["phi_deg"] + 2.0)

    score = S.score_episode(bag)
    total = S.overall([score, score])
    assert total["valid_estimates"] == 102 and total["ticks"] == 240
    assert total["params"]["phi_mae_deg"] == pytest.approx(2.0) and total["force"]["mae_z_n"] == pytest.approx(200.0)
    table = table_text([s], total)
    assert "Clay" in table and "overall" in table and "2.0" in table
    assert max(len(line) for line in table.splitlines()) <= 120


def test_a_bag_recorded_before_the_estimates_last_fields_is_read_with_them_zero(tmp_path, episode):
    """``/soil/estimate`` gained ``model_std_limit_x/z`` (the forecast law's part near the F_x limit);
    a bag recorded before, in the layout without them, is read with them 0 (no such part then) and
    scored as a bag of today's layout, and the recorder files such a message by its stamp (a replay
    of an old bag recorded again had lost every estimate as undecodable: a reviewer's); a layout
    that is neither is still refused, naming the topic."""
    from soil_bag_tools.bag_io import read_labelled_topic
    from soil_bag_tools.recorder import decode_stamp
    from soil_msgs_py import messages as M
    from soil_msgs_py import topics as T

    stamps = episode.stamps_ns
    estimates = [(int(stamps[k]), estimate(episode, k, k >= 59, min(k + 1, 60))) for k in range(len(episode))]
    for _, values in estimates:
        values[EST["model_std_abs_x"]], values[EST["model_std_limit_z"]] = 300.0, 0.15
    old = write_bag_with_estimates(tmp_path / "old" / episode.meta.name, episode, estimates, T.ESTIMATE_LAYOUTS_BEFORE[0])
    new = write_bag_with_estimates(tmp_path / "new" / episode.meta.name, episode, estimates)
    _, values = read_labelled_topic(old, T.ESTIMATE.name, T.ESTIMATE_FIELDS)
    assert (values[:, EST["model_std_limit_z"]] == 0).all() and (values[:, EST["model_std_abs_x"]] == 300).all()
    assert S.summarise(old) == S.summarise(new) | {"bag": str(old)}
    before = T.ESTIMATE_LAYOUTS_BEFORE[0]
    msg = M.make_labelled(M.TYPESTORE, 123456789, before, [estimates[70][1][EST[n]] for n in before])
    assert decode_stamp(T.ESTIMATE.name, T.ESTIMATE.msgtype, M.TYPESTORE.serialize_cdr(msg, T.ESTIMATE.msgtype)) == 123456789
    with pytest.raises(ValueError, match="label mismatch"):  # (without the older layouts: refused)
        M.parse_labelled(msg, T.ESTIMATE_FIELDS, T.ESTIMATE.name, older=())
    odd = write_bag_with_estimates(tmp_path / "odd" / episode.meta.name, episode, estimates, T.ESTIMATE_FIELDS[:-1])
    with pytest.raises(ValueError, match="/soil/estimate"):
        S.summarise(odd)


def test_summarise_names_the_bag_without_estimates(tmp_path, episode):
    bag = write_episode(tmp_path / "no_estimator", episode)
    with pytest.raises(ValueError, match=r"no topic /soil/estimate.*estimator"):
        S.summarise(bag)
    only_invalid = [(int(s), estimate(episode, k, False, min(k + 1, 59))) for k, s in enumerate(episode.stamps_ns)]
    bag = write_bag_with_estimates(tmp_path / "never_valid", episode, only_invalid)
    with pytest.raises(ValueError, match=r"no valid estimate.*59/60"):
        S.summarise(bag)


def test_the_demo_figure_draws_the_fused_soil_with_its_90_percent_band_where_it_is_valid(tmp_path, episode):
    """The figure showed the PINN's window estimates alone; a planner reads the fused soil and its
    std. φ's band is mean ± 1.645 std, c's not below 0, none before the first stretch."""
    from matplotlib.collections import PolyCollection

    from soil_bringup.scoring import score_episode
    from soil_bringup.summary_figure import draw

    rows = []
    for k, stamp in enumerate(episode.stamps_ns):
        values = estimate(episode, k, k >= 59, min(k + 1, 60))
        if k >= 90:  # the posterior valid from tick 90 on: φ 30° ± 2°, c 1 ± 2 kPa
            values[EST["fused_valid"]] = 1.0
            values[EST["phi_fused"]], values[EST["phi_std"]] = 30 * DEG, 2 * DEG
            values[EST["c_fused"]], values[EST["c_std"]] = 1000.0, 2000.0
        rows.append((int(stamp), values))
    score = score_episode(write_bag_with_estimates(tmp_path / episode.meta.name, episode, rows))
    fig = draw([score])
    ax_phi, ax_c = fig.axes[0], fig.axes[1]
    (phi_band,), (c_band,) = ([c for c in ax.collections if isinstance(c, PolyCollection)] for ax in (ax_phi, ax_c))
    phi_y, c_y = phi_band.get_paths()[0].vertices[:, 1], c_band.get_paths()[0].vertices[:, 1]
    assert phi_y.min() == pytest.approx(30 - 1.645 * 2, abs=0.01) and phi_y.max() == pytest.approx(30 + 1.645 * 2, abs=0.01)
    assert c_y.min() == 0.0 and c_y.max() == pytest.approx(1 + 1.645 * 2, abs=0.01)
    t_band = phi_band.get_paths()[0].vertices[:, 0]
    assert t_band.min() >= episode.time_s[90] - 1e-9  # nothing drawn before the posterior was valid
    import matplotlib.pyplot as plt
    plt.close(fig)
