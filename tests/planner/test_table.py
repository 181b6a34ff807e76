"""Look-up table: ID arithmetic, CSV round trip, interpolation and failure paths."""
import math

import numpy as np
import pytest

import planner.table
from planner.table import DEFAULT_TABLE_PATH, design_id, design_indices, design_parameters, load_table

pytestmark = pytest.mark.fast


@pytest.fixture(scope="module")
def table():
    return load_table()


def test_paper_id_numbering():
    assert design_id(0, 2, 0) == 15
    assert design_id(0, 2, 1) == 36
    assert design_id(0, 2, 2) == 57
    assert design_parameters(15)[:3] == (15e-3, 0.31e-3, 1.5)
    assert design_parameters(36)[:3] == (15e-3, 0.44e-3, 1.5)
    assert design_parameters(57)[:3] == (15e-3, 0.62e-3, 1.5)
    assert [design_id(*design_indices(i)) for i in range(1, 85)] == list(range(1, 85))


@pytest.mark.parametrize("args, name", [((7, 0, 0), "i_lambda"), ((0, 3, 0), "i_length"), ((0, 0, -1), "i_diameter")])
def test_design_id_rejects_out_of_range(args, name):
    with pytest.raises(ValueError, match=name):
        design_id(*args)


@pytest.mark.parametrize("bad", [0, 85, 2.5])
def test_design_indices_rejects_unknown(bad):
    with pytest.raises(ValueError, match="design_id"):
        design_indices(bad)


def test_shipped_table_is_complete(table):
    assert table.ids.tolist() == list(range(1, 85))
    assert table.voltages[0] == 0.0 and np.all(np.diff(table.voltages) > 0)
    np.testing.assert_allclose(table.theta[:, 0], table.theta0)
    np.testing.assert_allclose(table.prestretch_axial * table.prestretch_tangential, 2.5)
    assert np.all(np.isfinite(table.theta0)) and np.all(table.stiffness > 0) and np.all(table.safe_voltage > 0)
    beyond = table.voltages[None, :] > table.safe_voltage[:, None]
    assert np.all(np.isnan(table.theta[beyond])) and np.all(np.isfinite(table.theta[~beyond]))


def test_angle_at_interpolates_and_flags_beyond_limit(table):
    row = table.design(15)
    angles, valid = table.angle_at([15, 15, 15], [0.0, 2400.0, row.safe_voltage + 100.0])
    assert valid.tolist() == [True, True, False]
    assert angles[0] == pytest.approx(row.theta0)
    k = int(np.searchsorted(table.voltages, 2400.0))
    assert angles[1] == pytest.approx(table.theta[table.index_of([15])[0], k])
    assert angles[2] == pytest.approx(table.theta_at_safe_voltage[table.index_of([15])[0]])
    between, _ = table.angle_at([15], 450.0)
    lo, hi = table.theta[14, 1], table.theta[14, 2]
    assert min(lo, hi) <= between[0] <= max(lo, hi)


def test_unknown_ids_and_bad_voltage_are_rejected(table):
    with pytest.raises(ValueError, match=r"unknown design IDs: \[0, 99\]"):
        table.index_of([99, 1, 0])
    with pytest.raises(ValueError, match="voltage"):
        table.angle_at([1], -5.0)


def test_csv_round_trip(table, tmp_path):
    path = table.write_csv(tmp_path / "t.csv")
    again = load_table(path)
    np.testing.assert_allclose(again.theta, table.theta, rtol=1e-8, equal_nan=True)
    np.testing.assert_allclose(again.safe_voltage, table.safe_voltage)
    assert again.design(57).rod_diameter == pytest.approx(0.62e-3)


def test_missing_and_corrupt_files_give_clear_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="python -m planner table"):
        load_table(tmp_path / "none.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text(DEFAULT_TABLE_PATH.read_text().replace(",0.00031,", ",zero,", 1))
    with pytest.raises(ValueError, match="rod_diameter_m"):
        load_table(bad)
    bad.write_text("id,rod_length_m\n1,0.01\n")
    with pytest.raises(ValueError, match="lacks columns"):
        load_table(bad)
    assert math.isfinite(load_table().theta0[0])


def test_angle_at_matches_per_design_interpolation(table):
    rng = np.random.default_rng(5)
    ids = rng.integers(1, 85, 300)
    volts = rng.uniform(0.0, 4000.0, 300)
    angles, valid = table.angle_at(ids, volts)
    for design, v, angle, ok in zip(ids, volts, angles, valid):
        row = table.index_of([design])[0]
        limit = table.safe_voltage[row]
        usable = table.voltages < limit
        grid = np.append(table.voltages[usable], limit)
        values = np.append(table.theta[row, usable], table.theta_at_safe_voltage[row])
        assert ok == (v <= limit)
        assert angle == pytest.approx(np.interp(min(v, limit), grid, values), abs=1e-12)


def cut_copy(tmp_path, lines: int, cut_last_line_at: int | None = None):
    """The shipped table cut after ``lines`` lines (header included), optionally through the last line."""
    text = DEFAULT_TABLE_PATH.read_text().splitlines(keepends=True)[:lines]
    if cut_last_line_at is not None:
        text[-1] = text[-1][:cut_last_line_at]
    path = tmp_path / "cut.csv"
    path.write_text("".join(text))
    return path


def test_a_table_cut_between_rows_is_refused_naming_the_missing_ids(tmp_path):
    with pytest.raises(ValueError, match=r"cut.csv has 39 rows for the 84 design IDs, missing IDs 40, 41, 42"):
        load_table(cut_copy(tmp_path, 40))


def test_a_table_cut_inside_a_row_is_refused_naming_the_line(tmp_path):
    with pytest.raises(ValueError, match=r"cut.csv, line 40: 5 cells, the header has 21"):
        load_table(cut_copy(tmp_path, 40, cut_last_line_at=len("39,0.02,0.00031,1.5,1.")))


@pytest.mark.parametrize("column, value, message", [
    ("theta0_rad", "", r"line 11 \(design 10\): theta0_rad is empty or not finite"),
    ("stiffness_Nm_per_rad", "inf", r"line 11 \(design 10\): stiffness_Nm_per_rad is empty or not finite"),
    ("theta_1200V_rad", "nan", r"line 11 \(design 10\): the angle at 1200 V is empty or not finite"),
])
def test_a_non_finite_cell_is_refused_naming_the_file_and_row(tmp_path, column, value, message):
    lines = DEFAULT_TABLE_PATH.read_text().splitlines()
    header = lines[0].split(",")
    row = lines[10].split(",")
    row[header.index(column)] = value
    lines[10] = ",".join(row)
    path = tmp_path / "damaged.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=rf"damaged.csv, {message}"):
        load_table(path)


def test_angles_beyond_the_safe_voltage_may_stay_empty(table):
    assert np.isnan(table.theta).any()  # the shipped table has them, and loads


def test_a_write_that_fails_part_way_leaves_the_old_table(table, tmp_path, monkeypatch):
    path = table.write_csv(tmp_path / "t.csv")
    before = path.read_bytes()
    calls = iter(range(1000))

    def failing_format(value):
        if next(calls) == 500:  # the disk fills up in the middle of the rows
            raise OSError(28, "No space left on device")
        return original_format(value)

    original_format = planner.table._format
    monkeypatch.setattr(planner.table, "_format", failing_format)
    with pytest.raises(OSError, match="No space left"):
        table.write_csv(path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["t.csv"]  # no temporary file left behind
