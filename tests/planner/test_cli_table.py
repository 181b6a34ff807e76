"""`python -m planner` CLI: subcommand registry and the table / ogden-fit commands."""
import numpy as np

from planner.cli import build_parser, main
from planner.table import load_table
from softblock_config import config_file


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
    assert "32.2" in out and "stroke" in out and "BREAKDOWN" in out
    assert main(args + ["--voltage", "4000"]) == 1
    assert "no valid equilibrium (BREAKDOWN)" in capsys.readouterr().out
    assert main(["block", "--length", "0.015", "--diameter", "0.01", "--prestretch", "1.5"]) == 2
    assert "rod_diameter" in capsys.readouterr().err
