"""Per-block calibration offsets (config/block_calibration.yaml)."""
import math

import pytest

from planner.block_calibration import DEFAULT_CALIBRATION_PATH, load_block_calibration, parse_block_calibration

pytestmark = pytest.mark.fast


def test_shipped_file_loads():
    assert DEFAULT_CALIBRATION_PATH.is_file()
    assert load_block_calibration().blocks == {}


def test_offsets_by_serial(tmp_path):
    path = tmp_path / "cal.yaml"
    path.write_text("blocks:\n  SB-7: {design_id: 15, offset_rad: -0.02}\n  8: {design_id: 36, offset_rad: 0}\n")
    calibration = load_block_calibration(path)
    assert calibration.offset_for("SB-7", 15) == -0.02
    assert calibration.offset_for("8", 36) == 0.0
    assert calibration.offset_for("unknown", 15) == 0.0 and calibration.offset_for("", 15) == 0.0
    with pytest.raises(ValueError, match="calibrated as design 15, not 16"):
        calibration.offset_for("SB-7", 16)


def test_missing_file_means_no_offsets(tmp_path):
    assert load_block_calibration(tmp_path / "none.yaml").blocks == {}


@pytest.mark.parametrize(
    "document, message",
    [
        ({"blocks": {"A": {"design_id": 99, "offset_rad": 0.0}}}, "design_id"),
        ({"blocks": {"A": {"design_id": 1, "offset_rad": math.radians(30)}}}, "offset_rad"),
        ({"blocks": {"A": {"design_id": 1, "offset_rad": "x"}}}, "offset_rad"),
        ({"blocks": {"A": {"design_id": 1}}}, "exactly design_id and offset_rad"),
        ({"blocks": ["A"]}, "'blocks' mapping"),
    ],
)
def test_bad_entries_name_the_problem(document, message):
    with pytest.raises(ValueError, match=message):
        parse_block_calibration(document)


def test_invalid_yaml_is_reported(tmp_path):
    path = tmp_path / "cal.yaml"
    path.write_text("blocks: {A: [\n")
    with pytest.raises(ValueError, match="invalid YAML"):
        load_block_calibration(path)
