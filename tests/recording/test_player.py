"""Player: recorded timing order, recorded QoS (latched stays latched), filters, offset, loop,
/clock, command topics left out and state topics kept away from live clients unless asked for, and a clear
error for message types that cannot be imported."""
import subprocess
import sys

import pytest
import rclpy
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from rclpy.serialization import serialize_message
from recording_helpers import (Spinner, assembly, hv_state, sequence_event, stamp,
                               wait_for, write_recording)
from geometry_msgs.msg import TransformStamped
from rosgraph_msgs.msg import Clock
from softblock_interfaces.msg import Assembly, HvHeartbeat, HvState
from std_msgs.msg import Float64
from tf2_msgs.msg import TFMessage

from softblock_ros.assembly_state_node import AssemblyStateNode
from softblock_ros.estimator_node import EstimatorNode
from softblock_ros.hv_driver_node import HvDriverNode
from softblock_ros.planner_node import PlannerNode
from softblock_ros.sequencer_node import SequencerNode
from softblock_ros.sim_camera_node import SimCameraNode
from softblock_ros.qos import LATCHED
from softblock_ros.recording.message_types import UnknownMessageTypeError
from recording.mcap_file import RecordingWriter
from recording.playback import PlaybackOptions
from recording.topics import is_command_topic, is_state_topic
from softblock_ros.recording.player_node import PlayerNode
from recording.qos_profiles import parse_offered_qos
from softblock_ros.recording.qos_metadata import offered_qos_yaml, playback_qos

pytestmark = pytest.mark.integration

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
    player = PlayerNode(grasp_recording, PlaybackOptions(rate=2.0, include_state=True), context=ros_context)
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


BURST = 200  # latched samples recorded at one instant: many times the latched publisher's depth


def test_a_burst_on_a_latched_topic_reaches_a_subscriber_whole(ros_context, tmp_path):
    # A latched publisher keeps only its depth of samples; a replay that writes faster than they are sent and
    # acknowledged lost the oldest (the demo's /rosout, replayed fast, came back a few logs short).
    path = write_recording(str(tmp_path / "burst.mcap"),
                           [("/assembly/current", assembly(f"a{i}"), START) for i in range(BURST)],
                           {"/assembly/current": LATCHED})
    player = PlayerNode(path, PlaybackOptions(include_state=True), context=ros_context)
    listener = rclpy.create_node("listener", context=ros_context)
    received = collect(listener, Assembly, "/assembly/current", QoSProfile(depth=BURST))
    spinner = Spinner(ros_context, player, listener)
    try:
        publisher, = player.publishers_by_channel.values()
        wait_for(lambda: publisher.get_subscription_count() >= 1, "listener matched")
        player.start()
        wait_for(player.finished.is_set, "end of playback")
        wait_for(lambda: len(received) == BURST, "every latched sample")
    finally:
        spinner.close()
        player.destroy_node()
    assert [m.name for m in received] == [f"a{i}" for i in range(BURST)]


def test_topic_filters_and_start_offset_select_what_is_played(ros_context, grasp_recording):
    options = PlaybackOptions(rate=20.0, include="^/(hv|sequencer)/", exclude="events$",
                              start_offset_s=10 * STEP / 1e9)
    player = PlayerNode(grasp_recording, options, context=ros_context)
    try:
        assert [p.topic_name for p in player.publishers_by_channel.values()] == ["/replay/hv/state"]
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
    hv = collect(listener, HvState, "/replay/hv/state", QoSProfile(depth=100))
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
    # recorded time (2023), not wall time; at rate 20 a stall of the playback thread between two passes
    # on a loaded machine moves it past one pass (200 ms), so the bound is a minute of recorded time
    assert START <= clock_ns <= START + 60 * 1_000_000_000


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
    assert latched.history.short_key == "keep_last"  # a late joiner gets the latest, not every sample
    volatile = playback_qos(parse_offered_qos(""))
    assert volatile.durability.short_key == "volatile"
    assert volatile.history.short_key == "keep_all"  # a burst of the replay is never dropped unsent
    with pytest.raises(ValueError, match="offered_qos_profiles"):
        parse_offered_qos("history: keep_last")


@pytest.mark.parametrize("field, value", [("rate", 0.0), ("start_offset_s", -1.0),
                                          ("clock_frequency_hz", -5.0), ("delay_s", -1.0),
                                          ("include", "("), ("namespace", "replay/")])
def test_bad_playback_options_name_the_parameter(field, value):
    with pytest.raises(ValueError, match=field):
        PlaybackOptions(**{field: value}).validate()


@pytest.fixture
def recording_with_commands(tmp_path):
    """A stack's recording: hv/state, and what a live driver obeys (heartbeat, safe voltage)."""
    entries = [("/assembly/safe_voltage", Float64(data=2901.0), START)]
    entries += [("/hv/heartbeat", HvHeartbeat(session="0123456789abcdef", counter=i + 1, mac="0" * 64),
                  START + i * STEP) for i in range(SAMPLES)]
    entries += [("/hv/state", stamp(START + i * STEP, hv_state({"front": float(i)})),
                 START + i * STEP) for i in range(SAMPLES)]
    return write_recording(str(tmp_path / "stack.mcap"), sorted(entries, key=lambda e: e[2]),
                           {"/assembly/safe_voltage": LATCHED})


class DriverLike:
    """Subscribes as the HV driver does: the heartbeat (volatile) and the safe voltage (latched)."""

    def __init__(self, ros_context, namespace="/"):
        self.node = rclpy.create_node("driver_like", namespace=namespace, context=ros_context)
        self.heartbeats = collect(self.node, HvHeartbeat, "hv/heartbeat", QoSProfile(depth=10))
        self.safe_voltages = collect(self.node, Float64, "assembly/safe_voltage", LATCHED)
        self.states = collect(self.node, HvState, "hv/state", QoSProfile(depth=100))

    def got_the_last_state(self) -> bool:
        """The last replayed hv/state arrived (it stays in the publisher's history until
        delivered; earlier ones may be overwritten on a loaded machine)."""
        return any(s.channels[0].measured_voltage == SAMPLES - 1 for s in self.states)


def test_neither_commands_nor_state_reach_a_live_driver_or_client_by_default(ros_context, recording_with_commands):
    """Old: a default replay published the recorded hv/state into the live domain, where the sequencer took it
    for the live driver's (a SIGKILLed driver went unnoticed for 28 s). By default it goes under /replay."""
    driver, replay = DriverLike(ros_context), DriverLike(ros_context, namespace="/replay")
    player = PlayerNode(recording_with_commands, PlaybackOptions(), context=ros_context)
    spinner = Spinner(ros_context, player, driver.node, replay.node)
    try:
        assert sorted(p.topic_name for p in player.publishers_by_channel.values()) == ["/replay/hv/state"]
        state = next(iter(player.publishers_by_channel.values()))
        wait_for(lambda: state.get_subscription_count() >= 1, "the replay namespace's node to match")
        player.start()
        wait_for(player.finished.is_set, "end of playback")
        wait_for(replay.got_the_last_state, "the last hv/state sample under /replay")
        for topic in ("/hv/heartbeat", "/assembly/safe_voltage", "/hv/state"):
            assert driver.node.count_publishers(topic) == 0, topic
    finally:
        spinner.close()
        player.destroy_node()
    assert (driver.heartbeats, driver.safe_voltages, driver.states) == ([], [], [])
    assert player.published == SAMPLES


def test_include_state_plays_the_state_topics_under_their_own_names(ros_context, recording_with_commands):
    driver = DriverLike(ros_context)
    player = PlayerNode(recording_with_commands, PlaybackOptions(include_state=True), context=ros_context)
    spinner = Spinner(ros_context, player, driver.node)
    try:
        assert sorted(p.topic_name for p in player.publishers_by_channel.values()) == ["/hv/state"]
        state = next(iter(player.publishers_by_channel.values()))
        wait_for(lambda: state.get_subscription_count() >= 1, "the driver-like node to match")
        player.start()
        wait_for(driver.got_the_last_state, "the last hv/state sample")
    finally:
        spinner.close()
        player.destroy_node()


@pytest.mark.parametrize("flag, logged", [
    ([], "playing state topics ['/hv/state'] under /replay (--include-state plays them under their own names)"),
    (["--include-state"], "playing state topics ['/hv/state'] under their own names: a live client takes them")])
def test_cli_says_where_the_state_topics_go(recording_with_commands, flag, logged):
    result = subprocess.run([sys.executable, "-m", "softblock_ros.recording", "play", "--rate", "10",
                             recording_with_commands, *flag], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert logged in result.stderr


@pytest.mark.parametrize("topic, state", [("/hv/state", True), ("/robot1/hv/state", True), ("/diagnostics", True),
                                          ("/rosout", True), ("/assembly/current", True), ("/assembly/state", False),
                                          ("/sequencer/events", False), ("/hv/state_x", False), ("/tf", True),
                                          ("/tf_static", True), ("/sim/assembly_built", True), ("/tf_x", False)])
def test_which_topics_are_state_topics(topic, state):
    assert is_state_topic(topic) is state
    assert PlaybackOptions().published_name(topic) == ("/replay" + topic if state else topic)
    assert PlaybackOptions(include_state=True).published_name(topic) == topic
    assert PlaybackOptions(namespace="/x").published_name(topic) == "/x" + topic


def test_include_commands_plays_them_and_a_namespace_keeps_them_away(ros_context,
                                                                      recording_with_commands):
    live, replay = DriverLike(ros_context), DriverLike(ros_context, namespace="/replay")
    options = PlaybackOptions(include_commands=True, namespace="/replay")
    player = PlayerNode(recording_with_commands, options, context=ros_context)
    spinner = Spinner(ros_context, player, live.node, replay.node)
    try:
        assert sorted(p.topic_name for p in player.publishers_by_channel.values()) == [
            "/replay/assembly/safe_voltage", "/replay/hv/heartbeat", "/replay/hv/state"]
        publishers = player.publishers_by_channel.values()
        wait_for(lambda: all(p.get_subscription_count() >= 1 for p in publishers),
                 "the replay namespace's node to match every topic")
        player.start()
        wait_for(player.finished.is_set, "end of playback")
        wait_for(lambda: replay.got_the_last_state() and replay.heartbeats and replay.safe_voltages,
                 "the replayed heartbeat, safe voltage and last hv/state")
    finally:
        spinner.close()
        player.destroy_node()
    assert replay.safe_voltages[0].data == 2901.0
    assert (live.heartbeats, live.safe_voltages, live.states) == ([], [], [])


COMMAND_TOPICS = "['/assembly/safe_voltage', '/hv/heartbeat']"


@pytest.mark.parametrize("flag, logged", [
    ([], f"not playing command topics {COMMAND_TOPICS} (--include-commands plays them)"),
    (["--include-commands"], f"playing command topics {COMMAND_TOPICS}: a live node")])
def test_cli_says_which_command_topics_it_leaves_out_or_plays(recording_with_commands, flag,
                                                              logged):
    result = subprocess.run([sys.executable, "-m", "softblock_ros.recording", "play", "--rate",
                             "10", recording_with_commands, *flag], capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert logged in result.stderr


@pytest.mark.parametrize("make_node", [SimCameraNode, EstimatorNode, AssemblyStateNode, PlannerNode, SequencerNode])
def test_whatever_the_stacks_nodes_watch_a_default_replay_keeps_from_them(ros_context, make_node):
    """Old: the simulated camera's sim/assembly_built (latched: it draws what was built from it) went into the
    live domain with a default replay."""
    node = make_node(context=ros_context)
    try:
        topics = {subscription.topic_name for subscription in node.subscriptions}
    finally:
        node.destroy_node()
    assert topics and all(is_state_topic(topic) or is_command_topic(topic) for topic in topics), topics
    assert all(PlaybackOptions().published_name(topic).startswith("/replay/") for topic in topics
               if not is_command_topic(topic))


def test_a_default_replay_plays_tf_and_the_simulated_world_under_replay(ros_context, tmp_path):
    """Old: /tf, /tf_static and sim/assembly_built were replayed under their own names, beside the live ones."""
    tf = TFMessage(transforms=[TransformStamped(child_frame_id="a/block_1")])
    entries = [("/tf_static", tf, START), ("/sim/assembly_built", assembly(), START), ("/tf", tf, START + STEP)]
    path = write_recording(str(tmp_path / "tf.mcap"), entries, {"/tf_static": LATCHED, "/sim/assembly_built": LATCHED})
    player = PlayerNode(path, PlaybackOptions(), context=ros_context)
    try:
        names = sorted(p.topic_name for p in player.publishers_by_channel.values())
    finally:
        player.destroy_node()
    assert names == ["/replay/sim/assembly_built", "/replay/tf", "/replay/tf_static"]


def test_the_hv_drivers_inputs_are_all_command_topics(ros_context):
    """Whatever topics the real HV driver subscribes to are left out of a default replay: the
    signed heartbeat and the safe voltage. Its other inputs (claim and release of control, the
    ramp action) are services, which a player cannot call."""
    driver = HvDriverNode(context=ros_context,
                          parameter_overrides=[Parameter("autostart", value=False)])
    try:
        assert driver.trigger_configure() == TransitionCallbackReturn.SUCCESS
        topics = dict(driver.get_subscriber_names_and_types_by_node("hv_driver", "/"))
        services = {name for name, _ in driver.get_service_names_and_types_by_node("hv_driver", "/")}
    finally:
        driver.trigger_shutdown()
        driver.destroy_node()
    assert topics and all(is_command_topic(topic) for topic in topics), topics
    assert topics["/hv/heartbeat"] == ["softblock_interfaces/msg/HvHeartbeat"]
    assert {"/hv/claim_control", "/hv/release_control", "/hv/ramp/_action/send_goal"} <= services


def test_clock_during_the_delay_stands_at_the_recordings_start(ros_context, grasp_recording):
    options = PlaybackOptions(delay_s=1.0, clock_frequency_hz=50.0, include="hv")
    player = PlayerNode(grasp_recording, options, context=ros_context)
    listener = rclpy.create_node("clock_listener", context=ros_context)
    clock = collect(listener, Clock, "/clock", QoSProfile(depth=100))
    spinner = Spinner(ros_context, player, listener)
    try:
        player.start()
        wait_for(lambda: len(clock) >= 5, "/clock during the delay")
        during_delay = list(clock)
        player.stop()
    finally:
        spinner.close()
        player.destroy_node()
    assert player.published == 0  # all of it was still the delay
    assert {c.clock.sec * 1_000_000_000 + c.clock.nanosec for c in during_delay} == {START}
