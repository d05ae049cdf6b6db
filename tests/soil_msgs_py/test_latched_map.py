"""/soil/map is latched: a reader that joins after the cut (a planner of a later pass) and asks
for TRANSIENT_LOCAL gets the newest map at once; the graph's VOLATILE readers (the recorder) match
the same writer and get only what is sent after they join. Before, the writer was VOLATILE: a
late reader got no map until the next stretch of evidence, which after the cut never comes."""
from __future__ import annotations

import time

import pytest

from tests.ros_probe import next_domain_id

pytestmark = [pytest.mark.live, pytest.mark.timeout(60)]


def test_a_late_transient_local_reader_gets_the_newest_map_and_a_volatile_one_only_new_maps():
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    from soil_msgs_py import topics as T
    from soil_msgs_py.ros_adapter import publisher_qos, topic_qos

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=next_domain_id())
    try:
        writer_node = rclpy.create_node("map_writer", context=context)
        reader_node = rclpy.create_node("late_planner", context=context)
        pub = writer_node.create_publisher(PointCloud2, T.SOIL_MAP.name, publisher_qos(T.SOIL_MAP.name))
        for sec in (1, 2, 3):
            msg = PointCloud2()
            msg.header.stamp.sec = sec
            pub.publish(msg)
        got = {"latched": [], "volatile": []}
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        reader_node.create_subscription(PointCloud2, T.SOIL_MAP.name, lambda m: got["latched"].append(m.header.stamp.sec), latched)
        reader_node.create_subscription(PointCloud2, T.SOIL_MAP.name, lambda m: got["volatile"].append(m.header.stamp.sec),
                                        topic_qos(T.SOIL_MAP.name))
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(reader_node)
        executor.add_node(writer_node)

        def spin_until(done, timeout):
            end = time.monotonic() + timeout
            while not done() and time.monotonic() < end:
                executor.spin_once(timeout_sec=0.05)

        # the writer's history arrives in order, the newest last (a spin may take only the first of it)
        spin_until(lambda: 3 in got["latched"] and pub.get_subscription_count() == 2, 20)
        assert got["latched"] and got["latched"][-1] == 3, got  # the newest map, sent before it joined
        msg = PointCloud2()
        msg.header.stamp.sec = 4
        pub.publish(msg)
        spin_until(lambda: 4 in got["volatile"] and 4 in got["latched"], 20)
        assert got["volatile"] == [4] and got["latched"][-1] == 4, got  # the recorder's kind: nothing from before
        executor.shutdown()
    finally:
        rclpy.shutdown(context=context)


def test_the_map_writer_keeps_the_latched_depth_not_the_data_topics():
    """60 maps (30 s of stretches), as said: with the data topics' 120 taken as its floor, the
    writer kept 120 (an outside tester's late reader got 60 s of maps)."""
    from soil_msgs_py import topics as T
    from soil_msgs_py.graph import ESTIMATOR_PHYSICS_TOPIC, LATCHED_WRITER_DEPTH, publisher_qos_spec

    spec = publisher_qos_spec(T.SOIL_MAP.name)
    assert (spec.depth, spec.durability, spec.reliability) == (LATCHED_WRITER_DEPTH, "transient_local", "reliable")
    # the episode's event and the estimator's physics are states: their writers keep the newest alone,
    # so a latecomer is sent what holds now
    from soil_msgs_py.graph import SIM_EPISODE_TOPIC, TOPIC_QOS

    for topic in (SIM_EPISODE_TOPIC, ESTIMATOR_PHYSICS_TOPIC):
        spec = publisher_qos_spec(topic)
        assert (spec.depth, spec.durability, spec.reliability) == (1, "transient_local", "reliable")
        assert TOPIC_QOS[topic] == spec  # and its readers ask for the same
