"""The launcher and the nodes' warning read a params file's sections by ``section_matches``;
rcl decides which sections a node is given. They must agree, or a launch reads a value the
node never got (the world, the estimator's checkpoint). Before, ``/**/node`` did not match the
root-namespace ``/node``, which rcl gives it."""
from __future__ import annotations

import pytest

from soil_msgs_py.params_files import section_matches
from tests.ros_probe import next_domain_id

pytestmark = [pytest.mark.live, pytest.mark.timeout(120)]

KEYS = ["/**/n1", "/**", "**/n1", "/*/n1", "n1", "/n1", "/**/ns/n1", "ns/**", "/ns/*", "/**/*",
        "ns/n1", "/a/*/n1", "/*/*/n1", "other", "/**/other"]


def _given_by_rcl(params_file, namespace: str) -> tuple[str, set[int]]:
    """(fully qualified name, indices of KEYS whose section rcl gave the node ``n1``)."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(args=["--ros-args", "--params-file", str(params_file)], context=context,
               domain_id=next_domain_id())
    try:
        node = rclpy.create_node("n1", namespace=namespace, context=context,
                                 automatically_declare_parameters_from_overrides=True)
        given = {i for i in range(len(KEYS)) if node.has_parameter(f"p{i}")}
        name = node.get_fully_qualified_name()
        node.destroy_node()
        return name, given
    finally:
        rclpy.shutdown(context=context)


@pytest.mark.parametrize("namespace", ["", "/ns", "/a/ns"])
def test_a_section_applies_to_a_node_exactly_where_rcl_applies_it(tmp_path, namespace):
    params = tmp_path / "p.yaml"
    params.write_text("".join(f'"{key}":\n  ros__parameters:\n    p{i}: {i}\n' for i, key in enumerate(KEYS)))
    name, given = _given_by_rcl(params, namespace)
    ours = {i for i, key in enumerate(KEYS) if section_matches(key, name)}
    assert ours == given, {KEYS[i]: ("rcl" if i in given else "ours") for i in ours ^ given}
    assert given, name  # the file is one rcl read at all


def test_the_nodes_no_section_warning_reads_nested_namespace_maps_as_rcl_does(tmp_path):
    """``ns: {node: {ros__parameters: …}}`` is the node /ns/node's section for rcl; the node's
    "no section for this node" warning looked at the file's top-level keys only and said so."""
    import rclpy

    from soil_msgs_py.ros_adapter import params_file_warnings

    nested = tmp_path / "nested.yaml"
    nested.write_text("ns:\n  n1:\n    ros__parameters:\n      p: 1\n")
    other = tmp_path / "other.yaml"
    other.write_text("elsewhere:\n  n1:\n    ros__parameters:\n      p: 1\n")
    argv = ["--ros-args", "--params-file", str(nested), "--params-file", str(other)]
    context = rclpy.Context()
    rclpy.init(args=argv, context=context, domain_id=next_domain_id())
    try:
        node = rclpy.create_node("n1", namespace="/ns", context=context,
                                 automatically_declare_parameters_from_overrides=True)
        assert node.has_parameter("p")  # rcl applied the nested section
        warnings = params_file_warnings(argv, node)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    assert len(warnings) == 1 and str(other) in warnings[0] and str(nested) not in warnings[0], warnings
