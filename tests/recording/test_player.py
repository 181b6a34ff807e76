"""Player: recorded timing order, recorded QoS (latched stays latched), filters, offset, loop,
/clock, and a clear error for message types that cannot be imported."""
import subprocess
import sys

import pytest
import rclpy
from rclpy.qos import QoSProfile
from rclpy.serialization import serialize_message
from recording_helpers import (LATCHED, Spinner, assembly, hv_state, sequence_event, stamp,
                               wait_for, write_recording)
from rosgraph_msgs.msg import Clock
from softblock_interfaces.msg import Assembly, HvState

from softblock_ros.recording.message_types import UnknownMessageTypeError
from recording.mcap_file import RecordingWriter
from recording.playback import PlaybackOptions
from softblock_ros.recording.player_node import PlayerNode
from softblock_ros.recording.qos_metadata import (offered_qos_yaml, parse_offered_qos,
                                                  playback_qos)

START = 1_700_000_000_000_000_000
STEP = 10_000_000  # 10 ms between hv/state samples
SAMPLES = 20


@pytest.fixture
def grasp_recording(tmp_path):
    entries = [("/assembly/current", assembly("replayed"), START)]
    entries += [("/hv/state", stamp(START + i * STEP, hv_state({"front": 100.0 * i})),
                 START + i * STEP) for i in range(SAMPLES)]
    entries += [("/sequencer/events", stamp(START + 5 * STEP, sequence_event(0, "close",
                                                                             "started")),
                 START + 5 * STEP)]
    return write_recording(str(tmp_path / "grasp.mcap"), sorted(entries, key=lambda e: e[2]),
                           {"/assembly/current": LATCHED})


def collect(node, msg_type, topic, qos):
    received = []
    node.create_subscription(msg_type, topic, received.append, qos)
    return received


def test_replay_in_order_and_latched_topic_reaches_a_late_subscriber(ros_context,
                                                                     grasp_recording):
    player = PlayerNode(grasp_recording, PlaybackOptions(rate=2.0), context=ros_context)
    listener = rclpy.create_node("listener", context=ros_context)
    hv = collect(listener, HvState, "/hv/state", QoSProfile(depth=100))
    spinner = Spinner(ros_context, player, listener)
    try:
        hv_publisher = next(p for p in player.publishers_by_channel.values()
                            if p.topic_name == "/hv/state")
        wait_for(lambda: hv_publisher.get_subscription_count() >= 1, "listener matched")
        player.start()
        wait_for(player.finished.is_set, "end of playback")
        wait_for(lambda: len(hv) == SAMPLES, "every hv/state sample")
        late = collect(listener, Assembly, "/assembly/current", LATCHED)
        wait_for(lambda: late, "the latched assembly")
    finally:
        spinner.close()
        player.destroy_node()
    assert player.published == SAMPLES + 2
    assert [m.channels[0].measured_voltage for m in hv] == [100.0 * i for i in range(SAMPLES)]
    assert late[0].name == "replayed"


def test_topic_filters_and_start_offset_select_what_is_played(ros_context, grasp_recording):
    options = PlaybackOptions(rate=20.0, include="^/(hv|sequencer)/", exclude="events$",
                              start_offset_s=10 * STEP / 1e9)
    player = PlayerNode(grasp_recording, options, context=ros_context)
    try:
        assert [p.topic_name for p in player.publishers_by_channel.values()] == ["/hv/state"]
        player.start()
        wait_for(player.finished.is_set, "end of playback")
    finally:
        player.destroy_node()
    assert player.published == SAMPLES - 10


def test_loop_replays_until_stopped_and_clock_follows_recorded_time(ros_context,
                                                                    grasp_recording):
    options = PlaybackOptions(rate=20.0, loop=True, include="hv", clock_frequency_hz=50.0)
    player = PlayerNode(grasp_recording, options, context=ros_context)
    listener = rclpy.create_node("listener", context=ros_context)
    hv = collect(listener, HvState, "/hv/state", QoSProfile(depth=100))
    clock = collect(listener, Clock, "/clock", QoSProfile(depth=10))
    spinner = Spinner(ros_context, player, listener)
    try:
        player.start()
        wait_for(lambda: len(hv) > 2 * SAMPLES and clock, "more than two passes and /clock")
        player.stop()
    finally:
        spinner.close()
        player.destroy_node()
    assert player.finished.is_set()
    voltages = [m.channels[0].measured_voltage for m in hv]
    restarts = [later for earlier, later in zip(voltages, voltages[1:]) if later < earlier]
    assert restarts and set(voltages) <= {100.0 * i for i in range(SAMPLES)}
    clock_ns = clock[0].clock.sec * 1_000_000_000 + clock[0].clock.nanosec
    assert START <= clock_ns <= START + SAMPLES * STEP * 2


@pytest.fixture
def recording_with_unknown_type(tmp_path):
    path = str(tmp_path / "unknown.mcap")
    writer = RecordingWriter(path)
    mystery = writer.add_topic("/mystery", "no_such_msgs/msg/Thing", "", "",
                               definition="int32 x\n")
    writer.write(mystery, b"\x00\x01\x00\x00\x07\x00\x00\x00", START, START)
    known = writer.add_topic("/hv/state", "softblock_interfaces/msg/HvState",
                             offered_qos_yaml([QoSProfile(depth=10)]))
    writer.write(known, serialize_message(hv_state({"front": 1.0})), START + STEP, START + STEP)
    writer.close()
    return path


def test_unknown_type_stops_with_an_error_naming_type_and_topic(ros_context,
                                                                recording_with_unknown_type):
    with pytest.raises(UnknownMessageTypeError, match=r"no_such_msgs/msg/Thing \(topic /mystery\)"):
        PlayerNode(recording_with_unknown_type, context=ros_context)


def test_skip_unknown_plays_the_other_topics(ros_context, recording_with_unknown_type):
    player = PlayerNode(recording_with_unknown_type, PlaybackOptions(skip_unknown=True),
                        context=ros_context)
    try:
        player.start()
        wait_for(player.finished.is_set, "end of playback")
    finally:
        player.destroy_node()
    assert list(player.skipped) == ["/mystery"]
    assert player.published == 1


def test_cli_reports_unknown_type_and_exits_2(recording_with_unknown_type):
    result = subprocess.run([sys.executable, "-m", "softblock_ros.recording", "play",
                             recording_with_unknown_type], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2
    assert "no_such_msgs/msg/Thing" in result.stderr and "--skip-unknown" in result.stderr


def test_recorded_qos_round_trips_to_playback_qos():
    latched = playback_qos(parse_offered_qos(offered_qos_yaml([LATCHED])))
    assert (latched.durability.short_key, latched.reliability.short_key) == \
        ("transient_local", "reliable")
    assert playback_qos(parse_offered_qos("")).durability.short_key == "volatile"
    with pytest.raises(ValueError, match="offered_qos_profiles"):
        parse_offered_qos("history: keep_last")


@pytest.mark.parametrize("field, value", [("rate", 0.0), ("start_offset_s", -1.0),
                                          ("clock_frequency_hz", -5.0), ("delay_s", -1.0),
                                          ("include", "(")])
def test_bad_playback_options_name_the_parameter(field, value):
    with pytest.raises(ValueError, match=field):
        PlaybackOptions(**{field: value}).validate()
