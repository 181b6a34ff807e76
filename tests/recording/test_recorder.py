"""Recorder against real publishers of the stack's types; files read back by independent readers
(mcap + mcap-ros2-support, rosbags AnyReader) with the right topics, types, counts and contents."""
from pathlib import Path

import pytest
import rclpy
import yaml
from mcap.reader import make_reader
from rclpy.parameter import Parameter
from recording_helpers import (Spinner, assembly, assembly_state, hv_state, read_decoded,
                               sequence_event, stamp, wait_for)
from rosbags.highlevel import AnyReader
from softblock_interfaces.msg import Assembly, AssemblyState, HvState, SequenceEvent
from std_msgs.msg import Float64, String

from softblock_ros.qos import LATCHED
from softblock_ros.recording.recorder_node import RecorderNode

pytestmark = pytest.mark.integration

COUNT = 40
STREAMED = {"/hv/state": HvState, "/sequencer/events": SequenceEvent,
            "/assembly/state": AssemblyState, "/notes": String}
LATCHED_TOPICS = {"/assembly/current": "softblock_interfaces/msg/Assembly",
                  "/assembly/safe_voltage": "std_msgs/msg/Float64"}


def streamed_message(topic: str, index: int):
    return {"/hv/state": lambda: hv_state({"front": 10.0 * index, "back": 5.0 * index}),
            "/sequencer/events": lambda: sequence_event(index, f"step{index}", "started"),
            "/assembly/state": lambda: assembly_state({"front": [0.01 * index, -0.01 * index]}),
            "/notes": lambda: String(data=f"note {index}")}[topic]()


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Latched topics published before the recorder starts, then COUNT messages per topic."""
    path = str(tmp_path_factory.mktemp("rec") / "stack.mcap")
    context = rclpy.Context()
    rclpy.init(context=context)
    publisher_node = rclpy.create_node("stack", context=context)
    publisher_node.create_publisher(Assembly, "assembly/current", LATCHED).publish(assembly())
    publisher_node.create_publisher(Float64, "assembly/safe_voltage", LATCHED).publish(
        Float64(data=3500.0))
    publishers = {topic: publisher_node.create_publisher(msg_type, topic, 100)
                  for topic, msg_type in STREAMED.items()}
    recorder = RecorderNode(path, context=context, parameter_overrides=[
        Parameter("discovery_period_s", value=0.2), Parameter("flush_period_s", value=0.2),
        Parameter("exclude", value=r"^/(rosout|parameter_events)$")])  # exact counts: without the nodes' logs
    spinner = Spinner(context, publisher_node, recorder)
    try:
        expected_topics = sorted([*STREAMED, *LATCHED_TOPICS])
        wait_for(lambda: recorder.recorded_topics == expected_topics, "all topics subscribed")
        for publisher in publishers.values():
            wait_for(lambda: publisher.get_subscription_count() >= 1, "recorder matched")
        for index in range(COUNT):
            for topic, publisher in publishers.items():
                message = streamed_message(topic, index)
                publisher.publish(stamp(publisher_node, message) if hasattr(message, "header")
                                  else message)
        counts = recorder.writer.message_counts
        wait_for(lambda: all(counts[t] == COUNT for t in STREAMED), "every message recorded")
        # Latched samples arrive whenever their reader matches, which may be after the stream.
        wait_for(lambda: all(counts[t] == 1 for t in LATCHED_TOPICS), "latched samples recorded")
    finally:
        spinner.close()
        recorder.close_recording()
        recorder.destroy_node()
        publisher_node.destroy_node()
        rclpy.try_shutdown(context=context)
    return path


def test_file_has_ros2_profile_schemas_and_qos_metadata(recording):
    with open(recording, "rb") as stream:
        reader = make_reader(stream)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
    assert {chunk.compression for chunk in summary.chunk_indexes} == {"zstd"}
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == {*STREAMED, *LATCHED_TOPICS}
    for topic, channel in channels.items():
        schema = summary.schemas[channel.schema_id]
        assert (channel.message_encoding, schema.encoding) == ("cdr", "ros2msg")
        assert channel.metadata["topic_type_hash"].startswith("RIHS01_")
        offered = yaml.safe_load(channel.metadata["offered_qos_profiles"])
        durability = "transient_local" if topic in LATCHED_TOPICS else "volatile"
        assert [p["durability"] for p in offered] == [durability]
        assert offered[0]["reliability"] == "reliable"
        assert offered[0]["deadline"] == {"sec": 9223372036, "nsec": 854775807}
    assert summary.schemas[channels["/hv/state"].schema_id].name == \
        "softblock_interfaces/msg/HvState"


def test_mcap_ros2_reader_decodes_every_message(recording):
    topics = read_decoded(recording)
    assert {t: len(m) for t, m in topics.items()} == {
        **{t: COUNT for t in STREAMED}, **{t: 1 for t in LATCHED_TOPICS}}
    voltages = [m.channels[0].measured_voltage for _, m, _, _ in topics["/hv/state"]]
    assert voltages == [10.0 * i for i in range(COUNT)]
    assert [m.step_name for _, m, _, _ in topics["/sequencer/events"]] == \
        [f"step{i}" for i in range(COUNT)]
    assert topics["/assembly/state"][-1][1].chains[0].block_angles == \
        pytest.approx([0.01 * (COUNT - 1), -0.01 * (COUNT - 1)])
    assert topics["/assembly/current"][0][1].name == "gripper"
    assert topics["/assembly/safe_voltage"][0][1].data == 3500.0
    for _, _, log_time, publish_time in topics["/hv/state"]:
        assert 0 < publish_time <= log_time  # receipt is logged after the source stamped it


def test_rosbags_anyreader_reads_the_same_contents(recording):
    with AnyReader([Path(recording)]) as reader:
        assert {c.topic: (c.msgtype, c.msgcount) for c in reader.connections} == {
            **{t: (f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}", COUNT)
               for t, cls in STREAMED.items()},
            **{t: (type_name, 1) for t, type_name in LATCHED_TOPICS.items()}}
        decoded: dict = {}
        for connection, _, raw in reader.messages():
            decoded.setdefault(connection.topic, []).append(
                reader.deserialize(raw, connection.msgtype))
    hv = decoded["/hv/state"]
    assert [m.channels[1].measured_voltage for m in hv] == [5.0 * i for i in range(COUNT)]
    assert hv[3].channels[0].name == "front"
    assert list(decoded["/assembly/state"][-1].chains[0].block_angles) == \
        pytest.approx([0.01 * (COUNT - 1), -0.01 * (COUNT - 1)])
    assert decoded["/assembly/current"][0].name == "gripper"
    assert decoded["/notes"][7].data == "note 7"


def test_topic_list_records_only_the_listed_topics(ros_context, tmp_path):
    path = str(tmp_path / "listed.mcap")
    node = rclpy.create_node("stack", context=ros_context)
    node.create_publisher(Float64, "assembly/safe_voltage", LATCHED).publish(Float64(data=1.0))
    node.create_publisher(String, "notes", LATCHED).publish(String(data="not recorded"))
    recorder = RecorderNode(path, ["assembly/safe_voltage"], context=ros_context,
                            parameter_overrides=[Parameter("discovery_period_s", value=0.2)])
    spinner = Spinner(ros_context, node, recorder)
    try:
        wait_for(lambda: recorder.writer.message_counts.get("/assembly/safe_voltage"),
                 "the latched sample")
    finally:
        spinner.close()
        recorder.close_recording()
    assert recorder.recorded_topics == ["/assembly/safe_voltage"]
    assert list(read_decoded(path)) == ["/assembly/safe_voltage"]


def test_file_carries_rosbag2_metadata_as_ros2_bag_record_writes_it(recording):
    with open(recording, "rb") as stream:
        records = [m for m in make_reader(stream).iter_metadata() if m.name == "rosbag2"]
    assert len(records) == 1 and set(records[0].metadata) == {"serialized_metadata"}
    bag = yaml.safe_load(records[0].metadata["serialized_metadata"])
    assert list(bag) == ["version", "storage_identifier", "duration", "starting_time",
                         "message_count", "topics_with_message_count", "compression_format",
                         "compression_mode", "relative_file_paths", "files", "custom_data",
                         "ros_distro"]
    total = COUNT * len(STREAMED) + len(LATCHED_TOPICS)
    assert (bag["version"], bag["storage_identifier"], bag["message_count"]) == (9, "mcap", total)
    assert bag["relative_file_paths"] == ["stack.mcap"] and bag["ros_distro"] == "jazzy"
    with open(recording, "rb") as stream:
        statistics = make_reader(stream).get_summary().statistics
    assert bag["starting_time"] == {"nanoseconds_since_epoch": statistics.message_start_time}
    span = statistics.message_end_time - statistics.message_start_time
    assert bag["duration"] == {"nanoseconds": span}
    assert bag["files"] == [{"path": "stack.mcap", "starting_time": bag["starting_time"],
                             "duration": bag["duration"], "message_count": total}]
    topics = {t["topic_metadata"]["name"]: t for t in bag["topics_with_message_count"]}
    assert {name: t["message_count"] for name, t in topics.items()} == {
        **{t: COUNT for t in STREAMED}, **{t: 1 for t in LATCHED_TOPICS}}
    hv = topics["/hv/state"]["topic_metadata"]
    assert (hv["type"], hv["serialization_format"]) == ("softblock_interfaces/msg/HvState", "cdr")
    assert hv["type_description_hash"].startswith("RIHS01_")
    latched = topics["/assembly/current"]["topic_metadata"]["offered_qos_profiles"]
    assert latched[0]["durability"] == "transient_local"
