"""The shipped Foxglove layout (config/foxglove/softblock_layout.json), written from this description.

    python -m softblock_ros.foxglove_layout            # rewrite the shipped file
    python -m softblock_ros.foxglove_layout --check    # exit 1 if the shipped file differs

Panels: the HV channels against time (measured voltage and setpoint, current), the chain in 3D (the markers
and the TF frames, predicted and ``estimated/``), the camera silhouette, the diagnostics, the sequencer's step
over time and its last event. Every panel reads a topic by its full name and schema, as the foxglove_bridge
serves it and as a recording holds it, so the layout opens either. The panels' settings are the foxglove-sdk's
(``foxglove.layouts``); the file is the layout format Foxglove exports and imports (``configById`` +
``layout``). No ROS import.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import foxglove.layouts as fl
from softblock_config import config_file

LAYOUT_FILE = config_file("foxglove") / "softblock_layout.json"
ROOT_FRAME = "gripper_base"  # assembly_state's frame_id default
GRIPPER_CHANNELS = ("front", "back")


def _channel(name: str, field: str) -> str:
    return f'/hv/state.channels[:]{{name=="{name}"}}.{field}'


def _series(path: str, label: str, **style) -> fl.PlotSeries:
    # Received time: a live message's arrival, a recorded one's log time; the layout reads both alike.
    return fl.PlotSeries(value=path, label=label, enabled=True, timestamp_method="receiveTime", **style)


def panels() -> dict[str, object]:
    """Panel id (``Type!name``, as Foxglove names them) -> its foxglove.layouts config."""
    voltage = [_series(_channel(name, "measured_voltage"), f"{name} measured [V]") for name in GRIPPER_CHANNELS]
    voltage += [_series(_channel(name, "setpoint"), f"{name} setpoint [V]", line_style="dashed")
                for name in GRIPPER_CHANNELS]
    current = [_series(_channel(name, "measured_current"), f"{name} current [A]") for name in GRIPPER_CHANNELS]
    return {
        "Plot!hv_voltage": fl.PlotConfig(paths=voltage, show_legend=True, is_synced=True,
                                         y_axis_label="voltage [V]", x_axis_val="timestamp"),
        "Plot!hv_current": fl.PlotConfig(paths=current, show_legend=True, is_synced=True,
                                         y_axis_label="current [A]", x_axis_val="timestamp"),
        "3D!chain": fl.ThreeDeeConfig(
            follow_tf=ROOT_FRAME, fixed_frame=ROOT_FRAME,
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


def layout() -> dict:
    """The layout document: panel configs by id and their arrangement (rows of columns)."""
    configs = {panel_id: json.loads(config.to_json()) for panel_id, config in panels().items()}
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


def text() -> str:
    return json.dumps(layout(), indent=2) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m softblock_ros.foxglove_layout", description=__doc__.split("\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the shipped layout differs from this one")
    parser.add_argument("--out", type=Path, default=LAYOUT_FILE, help=f"file to write (default {LAYOUT_FILE})")
    args = parser.parse_args(argv)
    if args.check:
        same = args.out.is_file() and args.out.read_text() == text()
        print(f"{args.out}: {'up to date' if same else 'differs; rerun python -m softblock_ros.foxglove_layout'}")
        return 0 if same else 1
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text())
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
