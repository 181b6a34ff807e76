"""`python -m planner` CLI: subcommand registry, the table / ogden-fit commands and one-line input errors."""
import subprocess
import sys

import numpy as np
import pytest

from planner.cli import build_parser, main
from planner.table import DEFAULT_TABLE_PATH, load_table
from softblock_config import config_file

pytestmark = pytest.mark.fast


def test_registry_collects_command_modules():
    commands = build_parser()._subparsers._group_actions[0].choices
    assert {"table", "calibrate", "ogden-fit"} <= set(commands)


def test_table_command_regenerates_the_shipped_table(tmp_path, capsys):
    out = tmp_path / "table.csv"
    assert main(["table", "--out", str(out)]) == 0
    assert "84 designs" in capsys.readouterr().out
    fresh, shipped = load_table(out), load_table()
    np.testing.assert_allclose(fresh.theta, shipped.theta, rtol=1e-6, equal_nan=True)
    np.testing.assert_allclose(fresh.safe_voltage, shipped.safe_voltage)


def test_ogden_fit_command(capsys):
    assert main(["ogden-fit", str(config_file("ogden_test_data_example.csv"))]) == 0
    assert '"mu_Pa"' in capsys.readouterr().out


def test_errors_are_reported_not_raised(tmp_path, capsys):
    assert main(["ogden-fit", str(tmp_path / "missing.csv")]) == 2
    assert "not found" in capsys.readouterr().err


def test_block_command_reports_angle_stroke_and_limit(capsys):
    args = ["block", "--length", "0.015", "--diameter", "0.00031", "--prestretch", "1.5"]
    assert main(args + ["--voltage", "2400"]) == 0
    out = capsys.readouterr().out
    assert f"({np.degrees(load_table().design(15).theta0):.2f} deg)" in out  # ID 15, as in the table
    assert "stroke" in out and "BREAKDOWN" in out
    assert main(args + ["--voltage", "4000"]) == 1
    assert "no valid equilibrium (BREAKDOWN)" in capsys.readouterr().out
    assert main(["block", "--length", "0.015", "--diameter", "0.01", "--prestretch", "1.5"]) == 2
    assert "rod_diameter" in capsys.readouterr().err


@pytest.mark.parametrize("target, message", [("DIRECTORY", "is a directory"), ("/dev/full", "is not a regular file")])
def test_table_onto_a_directory_or_a_device_is_a_one_line_error(tmp_path, capsys, target, message):
    target = str(tmp_path) if target == "DIRECTORY" else target
    assert main(["table", "--out", target]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error and target in error


FULL_DISK = """
import resource, signal, sys
from planner.cli import main
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead
resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
sys.exit(main(["table", "--out", sys.argv[1]]))
"""


def test_table_write_failing_part_way_keeps_the_old_file_and_says_so_in_one_line(tmp_path):
    """The disk fills up after 4 KiB of the new table (a file size limit stands in for it)."""
    out = tmp_path / "table.csv"
    out.write_bytes(DEFAULT_TABLE_PATH.read_bytes())
    run = subprocess.run([sys.executable, "-c", FULL_DISK, str(out)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2
    assert run.stderr.count("\n") == 1 and "File too large" in run.stderr, run.stderr
    assert out.read_bytes() == DEFAULT_TABLE_PATH.read_bytes()
    load_table(out)


@pytest.mark.parametrize("pixel_size", ["0", "-0.001", "nan"])
def test_design_finger_refuses_a_pixel_size_that_is_not_positive(capsys, pixel_size):
    """Given for a sample object, 0 used to fall back to the catalogue's scale without a word."""
    assert main(["design-finger", "strawberry", "--blocks", "2", "--pixel-size", pixel_size]) == 2
    assert "pixel_size must be a positive number of m/pixel" in capsys.readouterr().err
