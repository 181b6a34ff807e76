"""The README's main job end to end: `python -m softblock_ros.demo` on the simulated backend, then its
recording replayed into a fresh ROS graph and recorded again, with the same analysis."""
import json
import math
import sys
import threading

import pytest
import rclpy
import yaml
from processes import run
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from softblock_config import config_file

from softblock_ros.client import wait_until
from recording.analysis import analyze
from recording.mcap_file import describe
from recording.playback import PlaybackOptions
from softblock_ros.recording.player_node import PlayerNode
from softblock_ros.recording.qos_metadata import RECORD_DEPTH
from softblock_ros.recording.recorder_node import RecorderNode

# stack: `make test` runs it after the other tiers, beside another stack module (tests/conftest.py)
pytestmark = pytest.mark.stack

DEMO_TIMEOUT = 240.0  # [s] liveness bound only; the demo takes about a minute on an idle 2-core machine
FINGER_GRASP_STEPS = ["above_object", "open_back", "surround_object", "close_back", "grip_front", "lift_object",
                      "carry_object", "lower_object", "release_front", "open_back_release", "withdraw",
                      "close_back_rest"]


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    # the live view on a free port: a fixed one would meet another suite's demo (or a user's) on this machine
    demo_run = run([sys.executable, "-m", "softblock_ros.demo", "--out", str(out), "--live-view-port", "0"],
                   timeout=DEMO_TIMEOUT)
    return demo_run, out


def test_demo_exits_zero_and_writes_its_outputs(demo):
    demo_run, out = demo
    assert demo_run.returncode == 0, demo_run.stdout[-3000:] + demo_run.stderr[-3000:]
    for name in ("fingers.png", "recording.png", "run.mcap", "summary.json", "stack.log"):
        assert (out / name).stat().st_size > 0, name
    assert "=== demo summary ===" in demo_run.stdout


def test_demo_names_the_live_views_address_once_it_serves(demo):
    demo_run, out = demo
    url = json.loads((out / "summary.json").read_text())["live_view"]
    assert url and url.startswith("ws://127.0.0.1:") and not url.endswith(":0"), url
    assert f"live view: open {url} in Foxglove" in demo_run.stdout


def test_demo_designs_the_papers_gripper_and_runs_the_six_step_grasp(demo):
    _, out = demo
    summary = json.loads((out / "summary.json").read_text())
    designs = summary["designs"]
    assert [len(designs["front"][side]["design_ids"]) for side in ("left", "right")] == [4, 4]
    assert [len(designs["back"][side]["design_ids"]) for side in ("left", "right")] == [5, 5]
    assert not any(designs[s][side]["collision"] for s in designs for side in ("left", "right"))
    grasp = summary["grasp"]
    assert grasp["success"], grasp["message"]
    assert list(grasp["steps"]) == FINGER_GRASP_STEPS
    channels = summary["recording"]["channels"]
    assert channels["front"]["peak_voltage"] == pytest.approx(2400.0, abs=30.0)
    assert channels["back"]["peak_voltage"] == pytest.approx(2400.0, abs=30.0)


def test_demo_fault_drill_switches_the_output_off_with_a_named_fault(demo):
    _, out = demo
    summary = json.loads((out / "summary.json").read_text())
    drill = summary["fault_drill"]
    assert drill["fault_text"].startswith("over_current")
    assert drill["output_enabled_after"] is False
    recorded = [fault for fault in summary["recording"]["faults"] if fault["event"] == "raised"]
    assert any(f["channel"] == "front" and "over_current" in f["faults"] for f in recorded), recorded


class RecorderPacedPlayer(PlayerNode):
    """A player that publishes a message only once the recorder holds all but half a queue of those before it.

    The recorder's queues keep the newest RECORD_DEPTH samples of a topic; a recorder that the host slows below
    the replay's rate would lose the oldest. Paced by what the recorder holds, the replay slows down with it
    instead, so what is recorded does not depend on the host's speed."""

    def __init__(self, path, options, recorded, **kwargs):
        super().__init__(path, options, **kwargs)
        self._recorded, self._sent = recorded, 0

    def _publish(self, channel, message) -> None:
        wait_until(lambda: self._sent - self._recorded() <= RECORD_DEPTH // 2, 120.0,
                   "the recorder to catch up with the replay")
        super()._publish(channel, message)
        self._sent += 1


def test_demo_recording_replayed_and_recorded_again_gives_the_same_analysis(demo, tmp_path):
    _, out = demo
    original = str(out / "run.mcap")
    replayed = str(tmp_path / "replayed.mcap")
    context = rclpy.Context()
    rclpy.init(context=context)
    # State topics under their own names, so the analysis reads the same topics; neither node logs to /rosout,
    # so the recorded /rosout holds the replayed logs only.
    recorder = RecorderNode(replayed, context=context, enable_rosout=False,
                            parameter_overrides=[Parameter("discovery_period_s", value=0.1)])
    player = RecorderPacedPlayer(original, PlaybackOptions(rate=40.0, include_state=True),
                                 lambda: sum(list(recorder.writer.message_counts.values())), context=context,
                                 enable_rosout=False)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(player)
    executor.add_node(recorder)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        replayed_topics = {c.topic for c in player.recording.channels if c.id in player.publishers_by_channel}
        wait_until(lambda: set(recorder.recorded_topics) >= replayed_topics, 30.0,
                   "the recorder to subscribe to every replayed topic")
        for publisher in player.publishers_by_channel.values():
            wait_until(lambda: publisher.get_subscription_count() >= 1, 30.0, "the recorder to match")
        player.start()
        wait_until(player.finished.is_set, 120.0, "the end of the replay")
        wait_until(lambda: sum(recorder.writer.message_counts.values()) == player.published, 30.0,
                   "every replayed message to be recorded")
    finally:
        executor.shutdown()
        spinner.join()
        player.destroy_node()
        recorder.destroy_node()
        rclpy.try_shutdown(context=context)
    # The replay holds what the recording holds; what the live run lost on the way to its recorder is a fact of
    # that run (its publishers' numbering), which a replay, renumbered by the player's publishers, cannot repeat.
    live, again = analyze(original), analyze(replayed)
    assert again["lost_samples"] == {}, again["lost_samples"]
    assert {**again, "lost_samples": live["lost_samples"]} == live


def test_demo_recording_lost_no_sample_on_the_way_to_the_recorder(demo):
    _, out = demo
    assert analyze(str(out / "run.mcap"))["lost_samples"] == {}


def test_demo_camera_images_and_estimates_are_recorded_and_show_the_fingers_perturbation(demo):
    _, out = demo
    summary = json.loads((out / "summary.json").read_text())
    topics = describe(str(out / "run.mcap"))["topics"]
    assert topics["/camera/silhouette"]["type"] == "sensor_msgs/msg/Image" and topics["/camera/silhouette"]["count"] > 0
    assert topics["/assembly/estimated"]["count"] > 0 and topics["/diagnostics"]["count"] > 0
    camera = yaml.safe_load(config_file("camera.yaml").read_text())["sim_camera"]["ros__parameters"]
    seen = summary["recording"]["estimated_chains"][camera["chain"]]
    assert seen["samples"] >= 3
    # The estimate differs from the prediction by the simulated blocks' offsets (4 blocks in the front fingers).
    assert seen["median_minus_predicted"] == pytest.approx(camera["block_offsets_rad"][:4], abs=math.radians(0.5))
