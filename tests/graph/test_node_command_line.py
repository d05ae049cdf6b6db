"""What a node's command line does with what is not a well-formed ROS argument: ``--help`` answers
with the parameters, an argument a node does not take and ROS arguments rcl cannot parse stop it
with exit 2 and one line naming them (no traceback, no node left running), and a params file with
no section for the node says so. Each node is its own process, as ``ros2 run`` starts it."""
from __future__ import annotations

from pathlib import Path

import pytest

from tests.ros_probe import NodeProc, next_domain_id, wait_until

pytestmark = [pytest.mark.live, pytest.mark.timeout(120)]

NODES = {  # console script -> one of its parameters
    "soil_sim_node": "world_mode",
    "anti_stall_controller": "target_depth_m",
    "pinn_estimator": "checkpoint",
    "soil_planner": "force_quantile",
}


def _run(script: str, args: list[str], tmp_path) -> tuple[int, str]:
    node = NodeProc(script, args, next_domain_id(), tmp_path)
    try:
        code = node.wait(timeout=60)
    finally:
        node.stop()
    return code, node.output


@pytest.mark.parametrize("script", sorted(NODES))
def test_help_lists_the_parameters_and_an_unknown_argument_is_refused(script, tmp_path):
    code, out = _run(script, ["--help"], tmp_path)
    assert code == 0, out
    assert out.startswith(f"usage: {script} [--ros-args") and f"  {NODES[script]} (" in out, out
    code, out = _run(script, ["--bogus-flag", "--ros-args", "-p", f"{NODES[script]}:=x"], tmp_path)
    assert code == 2, out
    assert f"{script}: error: unrecognised argument(s) --bogus-flag" in out and "Traceback" not in out, out
    # NAME:=VALUE without --ros-args: rcl took a word value as a remap rule and the node ran with the default
    code, out = _run(script, [f"{NODES[script]}:=x"], tmp_path)
    assert code == 2, out
    assert f"{script}: error: unrecognised argument(s) {NODES[script]}:=x (outside --ros-args, NAME:=VALUE" in out, out


def test_the_estimators_help_and_refusals_answer_without_loading_torch():
    """torch takes about 2 s to import: the estimator's --help and a refused argument answer without it."""
    import subprocess
    import sys

    check = ("import sys; from pinn_estimator.node import main; codes = (main(['pinn_estimator', '--help']), "
             "main(['pinn_estimator', '--bogus-flag'])); assert codes == (0, 2), codes; "
             "assert 'torch' not in sys.modules, 'torch was imported'")
    run = subprocess.run([sys.executable, "-c", check], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr


@pytest.mark.parametrize("args, needle", [
    (["--ros-args", "-p", "soil"], "Couldn't parse parameter override rule: '-p soil'"),
    (["--ros-args", "--params-file", "/nonexistent/params.yaml"], "Couldn't parse params file"),
    (["--ros-args", "--params-file", "BROKEN"], "Couldn't parse params file"),
])
def test_ros_arguments_rcl_cannot_parse_exit_2_in_one_line(args, needle, tmp_path):
    broken = tmp_path / "broken.yaml"
    broken.write_text("soil_sim_node: [\n")
    args = [str(broken) if a == "BROKEN" else a for a in args]
    for script in ("soil_sim_node", "soil_bag_record"):
        code, out = _run(script, args, tmp_path)
        assert code == 2, out
        assert f"{script}: cannot start: " in out and needle in out and "Traceback" not in out, out
        assert ", at /" not in out.split("cannot start: ")[1].splitlines()[0]  # rcl's C source locations cut


def test_a_namespace_too_long_for_the_nodes_names_exits_2_in_one_line(tmp_path):
    """rcl refuses a namespace that leaves its names (the node's parameter services) too long: a
    traceback before (rclpy's RCLError from the simulator, InvalidServiceNameException from the
    controller, whose service names are longer)."""
    for script, length in (("soil_sim_node", 300), ("anti_stall_controller", 230)):
        code, out = _run(script, ["--ros-args", "-r", f"__ns:=/{'a' * length}"], tmp_path)
        assert code == 2, out
        assert f"{script}: cannot start: " in out and "is too long or not a ROS name" in out, out
        assert "Traceback" not in out and ", at /" not in out, out


def test_a_params_file_with_no_section_for_the_node_is_named_and_one_giving_a_key_twice_refused(tmp_path):
    typo = tmp_path / "typo.yaml"
    typo.write_text("soil_plannr:\n  ros__parameters:\n    margin: 0.5\n")
    shared = tmp_path / "shared.yaml"
    shared.write_text("/**:\n  ros__parameters:\n    log_period_s: 0.0\n")
    twice = tmp_path / "twice.yaml"  # rcl would keep one of the two in silence: refused, as soil_launch refuses it
    twice.write_text("soil_planner:\n  ros__parameters:\n    margin: 0.8\n    margin: 0.9\n")
    code, out = _run("soil_planner", ["--ros-args", "--params-file", str(typo), "--params-file", str(twice)], tmp_path)
    assert code == 2, out
    assert f"soil_planner: cannot start: params file {twice}: key 'margin' appears twice in one mapping (lines 3 and 4)" \
        in out and "Traceback" not in out, out
    sample = Path(__file__).resolve().parents[2] / "bags" / "samples" / "default_loam_id060_v0.50_d0.200_s7"
    code, out = _run("soil_bag_play", [str(sample), "--ros-args", "--params-file", str(twice)], tmp_path)
    assert code == 2 and f"soil_bag_play: cannot start: params file {twice}: key 'margin' appears twice" in out, out
    node = NodeProc("soil_planner", ["--ros-args", "--params-file", str(typo), "--params-file", str(shared)],
                    next_domain_id(), tmp_path)
    try:
        wait_until(lambda: "nothing in it applies" in node.output, 30, "the params files' warnings")
    finally:
        code = node.stop()
    assert f"params file {typo} has no section for this node (/soil_planner; its sections: soil_plannr) " \
           "(is soil_plannr a misspelling of soil_planner?): nothing in it applies" in node.output, node.output
    assert str(shared) not in node.output  # '/**' applies to every node
    assert code == 0 and "Traceback" not in node.output, node.output


def test_a_python_warning_at_start_up_is_a_line_of_the_nodes_log(tmp_path):
    """A fusion config lacking keys: its warning had come as Python's, a source file, line and code
    line on stderr beside the node's log (an outside tester's); now a [WARN] line of the node's."""
    empty = tmp_path / "empty.json"
    empty.write_text("{}\n")
    node = NodeProc("pinn_estimator", ["--ros-args", "-p", f"fusion_config:={empty}"], next_domain_id(), tmp_path)
    try:
        wait_until(lambda: f"fusion config {empty} lacks" in node.output, 60, "the config's warning")
    finally:
        code = node.stop()
    line = next(t for t in node.output.splitlines() if f"fusion config {empty} lacks" in t)
    assert line.startswith("[WARN]") and "[pinn_estimator]" in line, node.output
    assert "UserWarning" not in node.output and "FusionConfig.load" not in node.output, node.output
    assert code == 0 and "Traceback" not in node.output, node.output
