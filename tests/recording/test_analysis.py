"""Analysis of a synthetic grasp recording, without ROS: peaks, step durations, faults, angles;
and the same summary after a replay is recorded again."""
import json
import os
import subprocess
import sys

import pytest
from mcap.exceptions import McapError
from rclpy.parameter import Parameter
from recording_helpers import (Spinner, assembly_state, hv_state, sequence_event, stamp, wait_for,
                               write_recording)
from softblock_interfaces.msg import HvChannelState

from recording.analysis import analyze, fault_names, format_summary, load, summarize
from recording.analysis_plot import plot
from recording.cli import main as recording_main
from recording.playback import PlaybackOptions
from softblock_ros.recording.player_node import PlayerNode
from softblock_ros.recording.recorder_node import RecorderNode

pytestmark = pytest.mark.integration

START = 1_700_000_000_000_000_000
TENTH = 100_000_000
FRONT = [0, 500, 1000, 2000, 3000, 2500, 1000, 0, 0, 0, 0]  # [V], one sample per 0.1 s
OVER_CURRENT, LINK = HvChannelState.FAULT_OVER_CURRENT, HvChannelState.FAULT_LINK
BACK_FAULTS = {6: (OVER_CURRENT, "over_current"), 7: (OVER_CURRENT | LINK, "over_current link")}
EVENTS = [(1.0, 0, "approach", "started", ""), (3.5, 0, "approach", "succeeded", ""),
          (3.5, 1, "close", "started", ""), (7.0, 1, "close", "failed", "over current"),
          (8.0, 2, "lift", "started", "")]  # (time in tenths, step, name, phase, message)


def at(tenths: float) -> int:
    return START + round(tenths * TENTH)


@pytest.fixture(scope="module")
def grasp(tmp_path_factory):
    entries = []
    for i, front in enumerate(FRONT):
        faults = {"back": BACK_FAULTS[i]} if i in BACK_FAULTS else {}
        entries.append(("/hv/state", stamp(at(i), hv_state({"front": front, "back": 100.0 * i},
                                                          faults)), at(i) + 1_000_000))
    for tenths, index, name, phase, message in EVENTS:
        entries.append(("/sequencer/events",
                        stamp(at(tenths), sequence_event(index, name, phase, message)),
                        at(tenths) + 2_000_000))
    for i in range(10):
        entries.append(("/assembly/state",
                        stamp(at(i + 0.5), assembly_state({"front": [0.1 * i, -0.2 * i]})),
                        at(i + 0.5)))
    path = str(tmp_path_factory.mktemp("analysis") / "grasp.mcap")
    return write_recording(path, sorted(entries, key=lambda entry: entry[2]))


def test_summary_of_voltages_steps_faults_and_angles(grasp):
    summary = analyze(grasp)

    assert summary["duration"] == pytest.approx(1.0)
    assert summary["message_counts"] == {"/assembly/state": 10, "/hv/state": 11,
                                         "/sequencer/events": 5}
    front, back = summary["channels"]["front"], summary["channels"]["back"]
    assert (front["peak_voltage"], front["peak_voltage_time"]) == (3000.0, pytest.approx(0.4))
    assert front["peak_current"] == pytest.approx(3000.0e-8)
    assert (back["peak_voltage"], back["samples"]) == (1000.0, 11)
    assert summary["hv_state_longest_silence"]["seconds"] == pytest.approx(0.1)  # one message per 0.1 s
    steps = [(s["step_name"], s["outcome"], s["duration"], s["message"])
             for s in summary["steps"]]
    assert steps == [("approach", "succeeded", pytest.approx(0.25), ""),
                     ("close", "failed", pytest.approx(0.35), "over current"),
                     ("lift", "unfinished", None, "")]
    faults = [(f["event"], f["channel"], pytest.approx(f["time"]), f["faults"])
              for f in summary["faults"]]
    assert faults == [("raised", "back", 0.6, ["over_current"]),
                      ("raised", "back", 0.7, ["link"]),
                      ("cleared", "back", 0.8, ["over_current", "link"])]
    chain = summary["chains"]["front"]
    assert chain["final_angles"] == pytest.approx([0.9, -1.8])
    assert chain["min_angles"] == pytest.approx([0.0, -1.8])
    assert chain["max_angles"] == pytest.approx([0.9, 0.0])


def test_the_longest_silence_of_the_driver_is_found_by_its_stamps_not_by_arrival(tmp_path):
    # Published at 0, 0.1, 0.2, then nothing until 0.9 s; the recorder received them in a burst at 1 s.
    tenths = [0, 1, 2, 9, 10]
    entries = [("/hv/state", stamp(at(t), hv_state({"front": 100.0 * t})), at(10) + i) for i, t in enumerate(tenths)]
    summary = analyze(write_recording(str(tmp_path / "silence.mcap"), entries))
    assert summary["hv_state_longest_silence"] == {"seconds": pytest.approx(0.7), "from": pytest.approx(0.2)}
    assert "hv/state: longest silence 0.700 s (from 0.200 s)" in format_summary(summary)
    one = analyze(write_recording(str(tmp_path / "one.mcap"), entries[:1]))
    assert one["hv_state_longest_silence"] is None


def test_fault_names_follow_the_bit_table():
    names = {1: "over_current", 4: "link"}
    assert fault_names(OVER_CURRENT | LINK | 128, names) == ["over_current", "link", "bit7"]


def test_cli_writes_png_and_json_without_the_ros_workspace_or_rclpy(grasp, tmp_path):
    """`python -m recording analyze` with the colcon workspace off the path: the core alone."""
    script = ("import importlib.util, runpy, sys; "
              "assert importlib.util.find_spec('softblock_ros') is None, 'the ROS workspace is on the path'; "
              f"sys.argv = ['recording', 'analyze', {grasp!r}, '--out-dir', {str(tmp_path)!r}]; "
              "import recording.cli; code = recording.cli.main(sys.argv[1:]); "
              "assert 'rclpy' not in sys.modules, 'analysis imported rclpy'; sys.exit(code)")
    env = {key: value for key, value in os.environ.items()
           if key not in ("PYTHONPATH", "AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH")}
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=env,
                            cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "channel front: peak 3.000 kV" in result.stdout
    assert (tmp_path / "grasp.png").read_bytes().startswith(b"\x89PNG")
    assert json.loads((tmp_path / "grasp.json").read_text()) == \
        json.loads(json.dumps(analyze(grasp)))


def test_cli_without_the_plot_writes_the_same_summary_and_no_png(grasp, tmp_path, capsys):
    assert recording_main(["analyze", grasp, "--out-dir", str(tmp_path), "--no-plot"]) == 0
    assert "channel front: peak 3.000 kV" in capsys.readouterr().out
    assert json.loads((tmp_path / "grasp.json").read_text()) == json.loads(json.dumps(analyze(grasp)))
    assert not (tmp_path / "grasp.png").exists()


def test_unfinished_file_is_refused_with_a_hint_to_recover(tmp_path):
    truncated = tmp_path / "cut.mcap"
    truncated.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)
    with pytest.raises(McapError, match="recover"):
        analyze(str(truncated))


def test_replay_recorded_again_gives_the_same_summary(grasp, ros_context, tmp_path):
    """The check a replay into a fresh stack will use: analyze(original) == analyze(replay). The state topics
    under their own names (include_state), and the nodes' logs (/rosout) left out, so that the counts compare."""
    player = PlayerNode(grasp, PlaybackOptions(rate=5.0, include_state=True), context=ros_context)
    recorder = RecorderNode(str(tmp_path / "replayed.mcap"), context=ros_context,
                            parameter_overrides=[Parameter("discovery_period_s", value=0.1),
                                                 Parameter("exclude", value=r"^/(rosout|parameter_events)$")])
    spinner = Spinner(ros_context, player, recorder)
    try:
        wait_for(lambda: set(recorder.recorded_topics) >= {
            "/hv/state", "/sequencer/events", "/assembly/state"}, "recorder subscribed")
        for publisher in player.publishers_by_channel.values():
            wait_for(lambda: publisher.get_subscription_count() >= 1, "recorder matched")
        player.start()
        wait_for(player.finished.is_set, "end of playback")
        wait_for(lambda: sum(recorder.writer.message_counts.values()) == player.published,
                 "every replayed message recorded")
    finally:
        spinner.close()
        player.destroy_node()
        recorder.destroy_node()
    assert analyze(str(tmp_path / "replayed.mcap")) == analyze(grasp)


def test_estimated_angles_are_kept_apart_from_the_prediction_compared_and_plotted(tmp_path):
    entries = []
    for i in range(6):
        entries.append(("/assembly/state", stamp(at(2 * i), assembly_state({"front": [0.1 * i, 0.2]})), at(2 * i)))
        entries.append(("/robot/assembly/estimated",
                        stamp(at(2 * i + 1), assembly_state({"front": [0.1 * i + 0.03, 0.2 - 0.01 * i]})),
                        at(2 * i + 1)))
    path = write_recording(str(tmp_path / "estimated.mcap"), entries)
    data = load(path)
    assert data.angles["front"]["angles"][-1] == pytest.approx([0.5, 0.2])
    assert data.estimated["front"]["angles"][-1] == pytest.approx([0.53, 0.15])
    chain = summarize(data)["estimated_chains"]["front"]
    assert chain["samples"] == 6
    assert chain["median_minus_predicted"] == pytest.approx([0.03, -0.025])
    assert "estimated - predicted, median: [+1.72, -1.43] deg" in format_summary(summarize(data))
    plot(data, str(tmp_path / "recording.png"))
    assert (tmp_path / "recording.png").stat().st_size > 10_000
