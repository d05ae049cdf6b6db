"""A parameter declared with a float default takes a whole number written without a point
(``-p margin:=1``, ``force_quantile: 0`` in a params file, a run-time set to 1) as that float.
rclpy types such a parameter DOUBLE and refused an INTEGER "expecting type DOUBLE", so the
planner's documented ``force_quantile:=0`` (the point plan) stopped it with exit 2."""
from __future__ import annotations

import pytest

from tests.ros_probe import NodeProc, next_domain_id, wait_until

pytestmark = [pytest.mark.live, pytest.mark.timeout(120)]


def test_a_node_started_with_whole_numbers_for_float_parameters_runs_with_those_values(tmp_path):
    params = tmp_path / "planner.yaml"
    params.write_text("soil_planner:\n  ros__parameters:\n    d_max_m: 0\n")  # refused as 0.0 (> 0), not as a type
    node = NodeProc("soil_planner", ["--ros-args", "-p", "force_quantile:=0", "-p", "margin:=1"], next_domain_id(), tmp_path)
    try:
        wait_until(lambda: "margin 1.0" in node.output or node.proc.poll() is not None, 60, "the planner's start line")
        assert node.proc.poll() is None, node.output
        assert "expecting type" not in node.output and "force quantile none (the point plan)" in node.output, node.output
    finally:
        node.stop()
    bad = NodeProc("soil_planner", ["--ros-args", "--params-file", str(params)], next_domain_id(), tmp_path)
    try:
        assert bad.wait(timeout=60) == 2, bad.output
        assert "d_max_m" in bad.output and "expecting type" not in bad.output, bad.output
        assert "[soil_planner]: cannot start: " in bad.output, bad.output  # the refusal under the node's name
    finally:
        bad.stop()


def test_a_run_time_set_of_a_whole_number_is_taken_as_the_float(tmp_path):
    import rclpy
    from rclpy.parameter import Parameter

    from soil_msgs_py.ros_adapter import declare_parameters

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=next_domain_id())
    try:
        node = rclpy.create_node("whole_numbers", context=context,
                                 parameter_overrides=[Parameter("gain", Parameter.Type.INTEGER, 2)])
        get = declare_parameters(node, {"gain": (0.5, "a gain"), "count": (3, "an integer stays one")})
        assert get("gain") == 2.0 and isinstance(get("gain"), float)
        (result,) = node.set_parameters([Parameter("gain", Parameter.Type.INTEGER, 4)])
        assert result.successful and get("gain") == 4.0 and isinstance(get("gain"), float)
        (result,) = node.set_parameters([Parameter("count", Parameter.Type.DOUBLE, 1.5)])
        assert not result.successful and get("count") == 3  # the reverse is not a whole number: refused as before
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
