"""soil_plot_episode as a real process: where its figure goes by default and which -o it refuses
before reading the bag (exit 2, naming -o)."""
from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from soil_bag_tools.bag_io import read_episode, write_episode
from soil_sim_node.rollout import run_episodes
from soil_sim_node.simulator import EpisodeSpec, SimConfig

BIN = Path(sys.executable).parent


def plot(*args, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "soil_plot_episode"), *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=60)


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> list[Path]:
    """Two episodes whose names differ only after their last dot (the depth and the seed)."""
    root = tmp_path_factory.mktemp("bags")
    specs = [EpisodeSpec("Sand", 20.0, 0.5, depth, seed=seed, duration_s=0.5) for depth, seed in ((0.1, 0), (0.2, 1))]
    return [write_episode(root / ep.meta.name, ep) for ep in run_episodes(SimConfig(world_mode="fee"), specs)]


def test_the_default_figure_of_each_bag_is_its_own(bags, tmp_path):
    """Path.with_suffix made both bags' figure fee_sand_id020_v0.50_d0.png: the second overwrote the first."""
    assert [b.name for b in bags] == ["fee_sand_id020_v0.50_d0.100_s0", "fee_sand_id020_v0.50_d0.200_s1"]
    for bag in bags:
        out = plot(bag, cwd=tmp_path)
        assert out.returncode == 0, out.stderr
        assert out.stdout.strip() == str(bag.parent / (bag.name + ".png"))
    assert sorted(p.name for p in bags[0].parent.glob("*.png")) == [b.name + ".png" for b in bags]


def test_a_figure_path_without_suffix_is_written_as_png_and_said(bags, tmp_path):
    out = plot(bags[0], "-o", "fig", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "fig.png" and [p.name for p in tmp_path.iterdir()] == ["fig.png"]


@pytest.mark.parametrize("out_arg, needle", [
    ("afile/fig.png", "'afile/fig.png': a parent of it is a file, not a directory"),
    ("fig.xyz", "'fig.xyz': matplotlib cannot write '.xyz' files; it writes "),
])
def test_an_unwritable_figure_path_is_refused_before_the_bag_is_read(tmp_path, out_arg, needle):
    """No bag is there: the -o refusal comes first (it came as a traceback, or after the bag was read)."""
    (tmp_path / "afile").write_text("x")
    out = plot(tmp_path / "no_such_bag", "-o", out_arg, cwd=tmp_path)
    assert out.returncode == 2
    assert f"argument -o/--out: {needle}" in out.stderr and "Traceback" not in out.stderr
    assert "no_such_bag" not in out.stderr and (out_arg != "fig.xyz" or " pdf, " in out.stderr)


def test_a_machines_bag_is_drawn_without_a_truth_it_does_not_have(tmp_path, monkeypatch):
    """A bag without /soil/ground_truth has no Θ: its figure drew two empty FEE(Θ) lines in the
    legend. They are left out; the measured forces stay."""
    import matplotlib.pyplot as plt

    from soil_sim_node import plot as plot_module

    ep = run_episodes(SimConfig(world_mode="fee"), [EpisodeSpec("Sand", 20.0, 0.5, 0.1, seed=0, duration_s=0.5)])[0]
    labels = {}
    closed = plt.close
    monkeypatch.setattr(plot_module.plt, "close", lambda fig: (labels.setdefault(len(labels), [
        t.get_text() for t in fig.axes[0].get_legend().get_texts()]), closed(fig)))
    for truth in (True, False):
        bag = write_episode(tmp_path / f"bag_{truth}", ep, ground_truth=truth)
        plot_module.plot_episode(read_episode(bag), tmp_path / f"{truth}.png")
    assert any("FEE" in t for t in labels[0]) and not any("FEE" in t for t in labels[1])
    assert {"$f_x^b$ measured", "$f_z^b$ measured"} <= set(labels[1])


def test_a_bag_without_a_planner_draws_the_episodes_target_and_one_with_it_the_planners(tmp_path, monkeypatch):
    """In a closed loop the controller cuts to /planner/target_depth: the figure drew the episode's
    0.2 m target there, a depth nothing cut to (an outside tester's finding)."""
    import matplotlib.pyplot as plt

    from soil_sim_node import plot as plot_module

    ep = run_episodes(SimConfig(world_mode="fee"), [EpisodeSpec("Sand", 20.0, 0.5, 0.1, seed=0, duration_s=0.5)])[0]
    bag = write_episode(tmp_path / "bag", ep)
    assert plot_module.planner_targets(bag, ep) is None  # no planner topic in the bag
    labels = {}
    closed = plt.close
    monkeypatch.setattr(plot_module.plt, "close", lambda fig: (labels.setdefault(len(labels), [
        t.get_text() for t in fig.axes[1].get_legend().get_texts()]), closed(fig)))
    plot_module.plot_episode(ep, tmp_path / "fixed.png")
    followed = (ep.time_s[::5], -ep.column("u_za")[::5])  # the controller cut to these: the loop closed
    assert plot_module.followed_planner(ep, followed)
    plot_module.plot_episode(ep, tmp_path / "loop.png", followed)
    assert "target $\\bar d_z$" in labels[0] and "planner's target $\\bar d_z$" in labels[1]
    # a planner beside an open loop (the controller cut to the episode's 0.1 m): its targets are advice,
    # and the figure had said the depth came from it (an outside tester's)
    advisory = (np.array([0.0, 0.25]), np.array([0.08, 0.12]))
    assert not plot_module.followed_planner(ep, advisory)
    plot_module.plot_episode(ep, tmp_path / "advisory.png", advisory)
    assert labels[2][:2] == ["cut depth $d$", "target $\\bar d_z$"] and "planner's target (not followed)" in labels[2]
    # followed part-way (a planner that died at 3/4, the controller on the episode's 0.1 m after): its share
    from soil_msgs_py.episode import OBSERVATION_FIELDS

    n = len(ep.time_s)
    observations = ep.observations.copy()
    observations[:, OBSERVATION_FIELDS.index("u_za")] = np.where(np.arange(n) < 3 * n // 4, -0.15, -0.1)
    died = dataclasses.replace(ep, observations=observations)
    share = plot_module.followed_share(died, (ep.time_s[: 3 * n // 4], np.full(3 * n // 4, 0.15)))
    assert share == pytest.approx(0.75, abs=0.02) and plot_module.followed_planner(died, (ep.time_s[:1], np.array([0.15])))
    plot_module.plot_episode(died, tmp_path / "died.png", (ep.time_s[: 3 * n // 4], np.full(3 * n // 4, 0.15)))
    assert "planner's target $\\bar d_z$" in labels[3] and "fallback $\\bar d_z$" in labels[3]


def test_a_gap_or_a_non_finite_value_is_said_not_drawn_over_in_silence(bags, tmp_path):
    """A repaired bag's dropped chunk is a gap the figure's lines cross; a NaN force a hole in them.
    Both were drawn without a word (the trainer's windows do not span either)."""
    import dataclasses

    ep = read_episode(bags[0])
    assert ep.problems() == []
    keep = np.ones(len(ep), bool)
    keep[10:16] = False
    gapped = dataclasses.replace(ep, **{k: getattr(ep, k)[keep] for k in
                                        ("stamps_ns", "observations", "forces", "known", "truth", "extras")})
    bag = write_episode(tmp_path / "gapped", gapped)
    out = plot(bag, "-o", tmp_path / "gap.png", cwd=tmp_path)
    assert out.returncode == 0 and (tmp_path / "gap.png").is_file(), out.stderr
    t = ep.time_s
    assert f"warning: {bag}: 1 gap(s) in its ticks ({t[9]:.2f}-{t[16]:.2f} s)" in out.stderr, out.stderr
    forces = ep.forces.copy()
    forces[7, 0] = np.nan
    said = dataclasses.replace(ep, forces=forces).problems()
    assert said == ["'f_x_b' is nan at tick 7 (1 non-finite values or beyond ±1e+09)"], said
