"""The shipped Foxglove layout: written by its generator (current), and for every stack that ships, not only the
gripper: each HV channel the driver or a shipped sequence drives is plotted, and the 3D view names no frame the
assembly state may not publish."""
import json

import pytest
import yaml
from softblock_config import config_file

from sequencing.schema import load_sequence_file
from softblock_ros import foxglove_layout

pytestmark = pytest.mark.fast


def plotted_channels(document: dict, panel: str, field: str) -> set[str]:
    paths = [series["value"] for series in document["configById"][panel]["paths"]]
    return {path.split('name=="')[1].split('"')[0] for path in paths if path.endswith(f".{field}")}


def test_the_shipped_layout_is_what_the_generator_writes():
    assert foxglove_layout.main(["--check"]) == 0


def test_every_channel_of_every_shipped_stack_is_plotted():
    document = json.loads(foxglove_layout.LAYOUT_FILE.read_text())
    driver = yaml.safe_load(config_file("hv_driver.yaml").read_text())["hv_driver"]["ros__parameters"]
    driven = {name for path in config_file("sequences").glob("*.yaml") for name in load_sequence_file(path).channels}
    expected = set(driver["channel_names"]) | driven
    assert {"trunk", "leg_front_left"} <= expected
    for panel, field in (("Plot!hv_voltage", "measured_voltage"), ("Plot!hv_voltage", "setpoint"),
                         ("Plot!hv_current", "measured_current")):
        assert plotted_channels(document, panel, field) == expected, (panel, field)


def test_the_3d_view_follows_the_root_of_the_tf_tree_not_a_named_frame():
    chain = json.loads(foxglove_layout.LAYOUT_FILE.read_text())["configById"]["3D!chain"]
    assert "followTf" not in chain and "fixedFrame" not in chain


def test_a_layout_for_channels_of_ones_own(tmp_path, capsys):
    out = tmp_path / "my_layout.json"
    assert foxglove_layout.main(["--channels", "left,right", "--out", str(out)]) == 0
    document = json.loads(out.read_text())
    assert plotted_channels(document, "Plot!hv_current", "measured_current") == {"left", "right"}
    assert foxglove_layout.main(["--channels", "left,right", "--out", str(out), "--check"]) == 0
    assert foxglove_layout.main(["--out", str(out), "--check"]) == 1  # not the shipped stack's channels
    assert "differs" in capsys.readouterr().out
