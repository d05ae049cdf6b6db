"""The bring-up tools refuse bad paths when their arguments are parsed, naming the flag (exit 2)."""
from __future__ import annotations

import pytest

from soil_bringup import cut_report, demo, launch


def test_a_tool_refuses_a_file_as_its_output_directory_before_it_runs(tmp_path, capsys):
    """soil_cut_report runs ~15 s of closed-loop cuts before writing: the refusal comes first."""
    (tmp_path / "taken").write_text("x")
    with pytest.raises(SystemExit) as exit_:
        cut_report.parse_args(["--out", str(tmp_path / "taken")])
    assert exit_.value.code == 2
    assert "argument --out" in capsys.readouterr().err


def test_soil_launch_refuses_a_params_file_that_does_not_exist(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        launch.parse_args(["--controller-params-file", str(tmp_path / "nosuch.yaml")])
    assert exit_.value.code == 2
    assert f"--controller-params-file {tmp_path / 'nosuch.yaml'}: no such file" in capsys.readouterr().err


@pytest.mark.parametrize("content, said", [
    (bytes(range(256)), " is not UTF-8 text (byte 128"),  # (a binary file: UnicodeDecodeError's traceback)
    (b"a: [1, 2\n", " is not YAML"),
    # rcl (and PyYAML) keep the last of a key given twice, in silence: a user cannot tell which they meant
    (b"soil_sim_node:\n  ros__parameters:\n    duration_s: 2.0\n    duration_s: 300.0\n",
     ": key 'duration_s' appears twice in one mapping (lines 3 and 4)"),
    (b"a: {k: 1, k: 2}\n", ": key 'k' appears twice in one mapping (lines 1 and 1)"),
])
def test_soil_launch_refuses_a_params_file_it_cannot_read_before_starting_anything(tmp_path, capsys, content, said):
    """A params file the nodes' rcl would refuse is refused by the launcher, naming the file."""
    path = tmp_path / "params.yaml"
    path.write_bytes(content)
    for flag in ("--sim-params-file", "--estimator-params-file"):
        with pytest.raises(SystemExit) as exit_:
            launch.parse_args([flag, str(path), "--namespace", "/a", "--estimator"])
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert f"{flag}: params file {path}{said}" in err, err


@pytest.mark.parametrize("args, said", [
    (["--controller-params-file", "{tmp}"], "--controller-params-file {tmp}: a directory, not a YAML file"),
    (["--record", "{tmp}/a", "--recorder-arg=--out={tmp}/b"], "the recorder writes where --record says"),
    (["--record", "{tmp}/a", "--recorder-arg=--out", "--recorder-arg={tmp}/b"], "the recorder writes where --record says"),
    (["--record", "{tmp}/a", "--recorder-arg=--ou={tmp}/b"], "the recorder writes where --record says"),
    (["--pacing", "lockstep", "--rate", "3"], "--rate 3 is the real-time factor of --pacing realtime"),
    (["--rate", "5000"], "--rate 5000 outside [0.01, 1000], the simulator's real-time factors"),
    (["--rate", "inf"], "--rate inf outside [0.01, 1000]"),
    (["--domain-id", "233"], "--domain-id: '233' is not a ROS domain id, a whole number in [0, 232]"),
])
def test_soil_launch_refuses_options_it_would_not_follow(tmp_path, capsys, args, said):
    """Each was taken without a word: a directory as a params file was "no such file", the
    recorder's own --out won over --record (the bags went elsewhere, --record's directory never
    made), a lockstep launch ignored --rate; a rate the simulator refuses was refused only once
    the graph was up."""
    with pytest.raises(SystemExit) as exit_:
        launch.parse_args([a.format(tmp=tmp_path) for a in args])
    assert exit_.value.code == 2
    assert said.format(tmp=tmp_path) in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_the_graph_tools_take_their_domain_from_ros_domain_id_and_refuse_one_that_is_no_domain(monkeypatch, capsys):
    """soil_launch failed with a traceback on a ROS_DOMAIN_ID that is no number and soil_demo took its
    own domain without a word (the benchmarks, which share the option, ignored the variable)."""
    for tool, own in ((launch, 0), (demo, demo.DEFAULT_DOMAIN_ID)):
        monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
        assert tool.parse_args([]).domain_id == own
        monkeypatch.setenv("ROS_DOMAIN_ID", " 7 ")
        assert tool.parse_args([]).domain_id == 7 and tool.parse_args(["--domain-id", "9"]).domain_id == 9
        for bad in ("abc", "-1", "233", "7.5", "010", "0x10", "1_0"):  # (rcl reads "010" as 8, "0x10" as 16)
            monkeypatch.setenv("ROS_DOMAIN_ID", bad)
            with pytest.raises(SystemExit) as exit_:
                tool.parse_args([])
            assert exit_.value.code == 2
            assert f"{bad!r} is not a ROS domain id" in capsys.readouterr().err
            assert tool.parse_args(["--domain-id", "9"]).domain_id == 9  # the option given, the variable is not read


@pytest.mark.parametrize("value", ["4000", "nan", "0"])
def test_the_demo_refuses_a_duration_the_simulator_would_refuse_before_the_graph_starts(value, capsys):
    with pytest.raises(SystemExit) as exit_:
        demo.parse_args(["--duration", value])
    assert exit_.value.code == 2
    assert f"--duration {float(value)} must be in (0, 3600] s" in capsys.readouterr().err


def test_the_cut_report_says_no_stall_in_words_not_as_an_infinite_ratio():
    assert cut_report._less_stall(14.28, 0.3) == "47.6× less"
    assert cut_report._less_stall(14.28, 0.0) == "none, against 14.28 s"
    assert cut_report._less_stall(0.0, 0.0, "x") == "neither stalled"
    # the soil-aware policy stalling where the aggressive depth did not read "0.0× less"
    assert cut_report._less_stall(0.0, 0.13) == "more: 0.13 s against 0.00 s"


def test_the_cut_report_names_patches_the_blade_never_reached_and_a_path_without_a_change():
    """A patch beyond the blade's travel had an empty row and the target line printed '-- s'; a
    path of one soil printed an empty bold target ('****'); a plan never within 20 % reads 'never'."""
    row = lambda soil, x, t, settle: {"soil": soil, "relative_density_pct": 90.0, "x_start_m": x, "time_s": t,
                                      "settle_s": settle}
    reached = [row("Sand", 0.0, 10.0, 1.9), row("Clay", 6.0, 4.0, None)]
    assert cut_report._settle_text(reached) == "never"
    assert cut_report._settle_text(reached[:1]) == "no soil change reached on this path"
    beyond = reached[:1] + [row("Clay", 9.0, 0.0, None)]
    assert cut_report._settle_text(beyond) == "no soil change reached on this path"
    words = cut_report.unreached_text(beyond, 7.1)
    assert words.startswith("not reached: Clay 90 % from 9 m") and "x = 7.1 m" in words, words
    assert cut_report.unreached_text(reached, 7.1) == ""
    # patches ending behind where the blade's edge starts: no duration reaches them (the hint said
    # one would), and the first patch cut is the start, not a change scored for the 2 s target
    behind = [row("Sand", 0.0, 0.0, None), row("Silt", 1.0, 0.0, None)] + reached
    words = cut_report.unreached_text(behind, 7.1)
    assert words.startswith("not reached: Sand 90 % from 0 m, Silt 90 % from 1 m (behind where the blade's edge "
                            "starts") and "longer --duration" not in words, words
    assert cut_report._settle_text(behind) == "never"  # Clay's alone, as on the path without them


def test_the_cut_report_names_the_soils_as_the_catalogue_does():
    """'--patch 0:sand:20' ran as Sand, and the header said 'sand' where the rows said 'Sand'."""
    args = cut_report.parse_args(["--patch", "0:sand:20", "--patch", "8:clay:80"])
    assert [p.soil for p in args.patches] == ["Sand", "Clay"] and args.spec.soil == "Sand"


def test_a_force_quantile_of_0_is_refused_by_the_cut_report_without_offering_it_and_taken_by_the_node(capsys):
    """0 means the PINN's point plan only in the planner node's parameter: the report, which plans
    from the posterior, had refused it while offering it ("or 0 for the PINN's point plan")."""
    from soil_planner.node import PLANNER_SETTINGS
    from soil_planner.stretch_planner import from_parameters

    with pytest.raises(SystemExit) as exit_:
        cut_report.parse_args(["--force-quantile", "0"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "force_quantile=0.0 must be in [0.5, 1)" in err and "or 0" not in err, err
    settings = dict(margin=0.85, d_max_m=0.3, cut_speed_m_s=0.5, include_residual=False, terms=(), force_quantile=0.0,
                    sensor_anchor=True, bound_law=[])
    assert set(settings) == set(PLANNER_SETTINGS) and from_parameters(settings).force_quantile is None
    with pytest.raises(ValueError, match=r"force_quantile=1.5 must be in \[0.5, 1\) .*, or 0 for the PINN's point plan"):
        from_parameters({**settings, "force_quantile": 1.5})


def test_the_cut_report_refuses_a_soil_without_a_failure_wedge_even_where_the_blade_never_goes(tmp_path, capsys):
    """φ = 0 (an undrained clay) gives the FEE no wedge: the sweep raised a traceback, even for a
    patch 500 m along a 4 s path; now the argument check refuses it, naming the soil, as
    soil_sim_batch does."""
    soils = tmp_path / "soils.yaml"
    soils.write_text("soils:\n  - {name: Undrained, phi_deg: [0, 0], cohesion_pa: [30000, 50000], "
                     "unit_weight_n_m3: [16000, 20000]}\n")
    with pytest.raises(SystemExit) as ended:
        cut_report.parse_args(["--worlds", "fee", "--soil-file", str(soils), "--patch", "0:Sand:20",
                               "--patch", "500:Undrained:50", "--out", str(tmp_path / "out")])
    assert ended.value.code == 2
    assert "soil 'Undrained' at I_d 50 %: phi=0° gives the FEE no failure wedge" in capsys.readouterr().err
    assert cut_report.parse_args(["--worlds", "fee", "fee", "--out", str(tmp_path / "out")]).worlds == ["fee"]


def test_the_cut_report_takes_a_checkpoint_and_fusion_config_of_ones_own_for_one_world(tmp_path, capsys):
    """``--checkpoint`` / ``--fusion-config`` (an outside tester's own model could only be judged live):
    one world's, read before the sweeps; the setup carries them to the soil-aware policy."""
    import torch

    from pinn_estimator.fusion_config import FusionConfig
    from pinn_estimator.fusion_calibration import config_path
    from pinn_estimator.shipped import shipped_checkpoint

    import numpy as np

    from pinn_estimator.checkpoint import save_checkpoint
    from pinn_estimator.model import EstimatorNet, ModelConfig

    free = tmp_path / "free.pt"  # no soil parameters: it had failed with a traceback after the depth sweep
    net = EstimatorNet(ModelConfig(kind="physics_free", d_model=16, n_heads=2, n_layers=1, ff_dim=32), np.zeros(9), np.ones(9))
    save_checkpoint(free, net, train_config={}, dataset={}, split={}, metrics={}, history={})
    fee_model, default_config = str(shipped_checkpoint("fee")), str(config_path("default"))
    for args, said in ((["--checkpoint", fee_model], "one world's"),
                       (["--worlds", "fee", "--checkpoint", str(tmp_path / "none.pt")], "does not exist"),
                       (["--worlds", "fee", "--checkpoint", str(free)], "--checkpoint: model kind='physics_free'"),
                       (["--worlds", "fee", "--fusion-config", default_config], "calibrated in the default world")):
        with pytest.raises(SystemExit) as exit_:
            cut_report.parse_args(["--out", str(tmp_path / "o"), *args])
        assert exit_.value.code == 2 and said in capsys.readouterr().err
    mine = tmp_path / "mine.json"
    FusionConfig(world="default", forecast_abs_std_n=(777.0, 7.0)).save(mine)
    args = cut_report.parse_args(["--worlds", "default", "--checkpoint", fee_model, "--fusion-config", str(mine),
                                  "--out", str(tmp_path / "o")])
    setup = cut_report.SoilAwareSetup("default", checkpoint=args.checkpoint, fusion_config=args.fusion_config)
    estimator = setup.estimator(lambda _: None)
    assert torch.equal(next(estimator.model.parameters()), next(cut_report.load_model(fee_model)[0].parameters()))
    assert estimator.posterior.cfg.forecast_abs_std_n == (777.0, 7.0)
