"""The shipped Foxglove layout (config/foxglove/softblock_layout.json), written from this description.

    python -m softblock_ros.foxglove_layout            # rewrite the shipped file
    python -m softblock_ros.foxglove_layout --check    # exit 1 if the shipped file differs
    python -m softblock_ros.foxglove_layout --channels left,right --out my_layout.json   # a rig of your own

Panels: the HV channels against time (measured voltage and setpoint, current), the chain in 3D (the markers
and the TF frames, predicted and ``estimated/``), the camera silhouette, the diagnostics, the sequencer's step
over time and its last event. The shipped layout plots every channel of the shipped stack: the driver's
(config/hv_driver.yaml: the gripper's) and every shipped sequence's (the trunk's, the legged robot's), so it
serves each of them; the 3D view follows the root of the TF tree, whatever ``frame_id`` the assembly state is
given. Every panel reads a topic by its full name and schema, as the foxglove_bridge serves it and as a recording
holds it, so the layout opens either. The panels' settings are the foxglove-sdk's (``foxglove.layouts``); the file
is the layout format Foxglove exports and imports (``configById`` + ``layout``). No ROS import.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import foxglove.layouts as fl
from softblock_config import config_file

from planner.bounded_yaml import load_yaml_file
from sequencing.schema import load_sequence_file

LAYOUT_FILE = config_file("foxglove") / "softblock_layout.json"


def stack_channels() -> list[str]:
    """The HV channels of the shipped stack: the driver's, then those of each shipped sequence, once each."""
    driver = load_yaml_file(config_file("hv_driver.yaml"))["hv_driver"]["ros__parameters"]["channel_names"]
    sequences = [load_sequence_file(path).channels for path in sorted(config_file("sequences").glob("*.yaml"))]
    return list(dict.fromkeys([*driver, *(name for channels in sequences for name in channels)]))


def _channel(name: str, field: str) -> str:
    return f'/hv/state.channels[:]{{name=="{name}"}}.{field}'


def _series(path: str, label: str, **style) -> fl.PlotSeries:
    # Received time: a live message's arrival, a recorded one's log time; the layout reads both alike.
    return fl.PlotSeries(value=path, label=label, enabled=True, timestamp_method="receiveTime", **style)


def panels(channels: list[str]) -> dict[str, object]:
    """Panel id (``Type!name``, as Foxglove names them) -> its foxglove.layouts config, plotting ``channels``."""
    voltage = [_series(_channel(name, "measured_voltage"), f"{name} measured [V]") for name in channels]
    voltage += [_series(_channel(name, "setpoint"), f"{name} setpoint [V]", line_style="dashed")
                for name in channels]
    current = [_series(_channel(name, "measured_current"), f"{name} current [A]") for name in channels]
    return {
        "Plot!hv_voltage": fl.PlotConfig(paths=voltage, show_legend=True, is_synced=True,
                                         y_axis_label="voltage [V]", x_axis_val="timestamp"),
        "Plot!hv_current": fl.PlotConfig(paths=current, show_legend=True, is_synced=True,
                                         y_axis_label="current [A]", x_axis_val="timestamp"),
        "3D!chain": fl.ThreeDeeConfig(
            camera_state=fl.ThreeDeeCameraState(distance=0.4, perspective=True, phi=60.0, theta_offset=45.0),
            topics={"/assembly/markers": fl.BaseRendererRosMarkerTopicSettings(visible=True)},
            scene=fl.BaseRendererSceneSettings(transforms=fl.BaseRendererTransforms(
                visible=True, show_label=True, axis_size=0.01, label_size=0.004))),
        "Image!camera": fl.ImageConfig(image_mode=fl.ImageModeConfig(image_topic="/camera/silhouette")),
        "DiagnosticSummary!diagnostics": fl.DiagnosticsSummaryConfig(topic_to_render="/diagnostics",
                                                                     sort_by_level=True),
        "StateTransitions!sequencer_step": fl.StateTransitionsConfig(paths=[
            fl.StateTransitionsSeries(value="/sequencer/events.step_name", label="step"),
            fl.StateTransitionsSeries(value="/sequencer/events.phase", label="phase")], is_synced=True),
        "RawMessages!sequencer_event": fl.RawMessagesConfig(topic_path="/sequencer/events", expansion="all"),
    }


def _split(direction: str, first, second, percentage: float = 50.0) -> dict:
    return {"direction": direction, "first": first, "second": second, "splitPercentage": percentage}


def layout(channels: list[str]) -> dict:
    """The layout document for ``channels``: panel configs by id and their arrangement (rows of columns)."""
    configs = {panel_id: json.loads(config.to_json()) for panel_id, config in panels(channels).items()}
    plots = _split("column", "Plot!hv_voltage", "Plot!hv_current", 60.0)
    views = _split("column", "3D!chain", "Image!camera", 60.0)
    sequencer = _split("column", "StateTransitions!sequencer_step", "RawMessages!sequencer_event", 40.0)
    status = _split("column", sequencer, "DiagnosticSummary!diagnostics", 50.0)
    arrangement = _split("row", plots, _split("row", views, status, 55.0), 40.0)
    return {"configById": configs, "globalVariables": {}, "userNodes": {}, "playbackConfig": {"speed": 1.0},
            "layout": arrangement}


def topics_read(document: dict) -> set[str]:
    """The topics the layout's panels read (the part of each path before its first field)."""
    found = set()

    def visit(value):
        if isinstance(value, dict):
            for key, item in value.items():
                if key.startswith("/"):
                    found.add(key)
                visit(item)
        elif isinstance(value, list):
            for item in value:
                visit(item)
        elif isinstance(value, str) and value.startswith("/"):
            found.add(value.split(".", 1)[0])

    visit(document["configById"])
    return found


def text(channels: list[str]) -> str:
    return json.dumps(layout(channels), indent=2) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m softblock_ros.foxglove_layout", description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the shipped layout differs from this one")
    parser.add_argument("--out", type=Path, default=LAYOUT_FILE, help=f"file to write (default {LAYOUT_FILE})")
    parser.add_argument("--channels", type=lambda names: [n for n in names.split(",") if n],
                        help="comma-separated HV channels to plot (default: every channel of the shipped stack)")
    args = parser.parse_args(argv)
    channels = args.channels or stack_channels()
    if args.check:
        same = args.out.is_file() and args.out.read_text() == text(channels)
        print(f"{args.out}: {'up to date' if same else 'differs; rerun python -m softblock_ros.foxglove_layout'}")
        return 0 if same else 1
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text(channels))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
