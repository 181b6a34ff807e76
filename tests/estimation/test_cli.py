"""`python -m estimation`: render, estimate and calibrate from files, exit codes and errors."""
import json
import math
import subprocess
import sys

import pytest
import yaml

from estimation.cli import main
from planner.block_calibration import load_block_calibration

pytestmark = pytest.mark.fast

ASSEMBLY = """\
name: rig
chains:
  - name: finger
    hv_channel: main
    blocks: [{id: 36, serial: SB-1}, {id: 15, serial: SB-2}, {id: 22, serial: SB-3}]
"""


@pytest.fixture
def assembly(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text(ASSEMBLY)
    return path


def render(capsys, assembly, out, *extra):
    assert main(["render", "--assembly", str(assembly), "--pixel-size", "2.5e-4", "--out", str(out), *extra]) == 0
    base = capsys.readouterr().out.split("--base ")[1].split()
    return base[:3] + (["--mirrored"] if "--mirrored" in extra else [])


def test_render_then_estimate_as_built_with_json_and_png(tmp_path, capsys, assembly):
    base = render(capsys, assembly, tmp_path / "chain.png", "--offset", "2=3", "--angle", "1.0", "--mirrored")
    code = main(["estimate", str(tmp_path / "chain.png"), "--assembly", str(assembly), "--pixel-size", "2.5e-4",
                 "--base", *base, "--json", str(tmp_path / "out.json"), "--png", str(tmp_path / "out.png")])
    printed = capsys.readouterr().out
    assert code == 0 and "finger: as built" in printed
    document = json.loads((tmp_path / "out.json").read_text())
    assert document["blocks"][1]["offset_rad"] == pytest.approx(math.radians(3.0), abs=math.radians(0.5))
    assert (tmp_path / "out.png").stat().st_size > 10_000


def test_a_mistake_exits_1_and_is_printed(tmp_path, capsys, assembly):
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(ASSEMBLY.replace("{id: 15, serial: SB-2}", "{id: 8, serial: SB-2}"))
    base = render(capsys, wrong, tmp_path / "chain.png")
    code = main(["estimate", str(tmp_path / "chain.png"), "--assembly", str(assembly), "--pixel-size", "2.5e-4", "--base", *base])
    assert code == 1
    assert "block 2: design" in capsys.readouterr().out


def test_calibrate_writes_the_calibration_file(tmp_path, capsys, assembly):
    frame = ["--frame", "0.06", "0.01", "480", "440", "--angle", "1.2"]
    base = render(capsys, assembly, tmp_path / "rest.png", "--offset", "1=-1.5", *frame)
    render(capsys, assembly, tmp_path / "on.png", "--offset", "1=-1.5", "--voltage", "2400", *frame)
    target = tmp_path / "calibration.yaml"
    target.write_text("blocks:\n  SB-77: {design_id: 57, offset_rad: 0.01}\n")
    code = main(["calibrate", "--image", str(tmp_path / "rest.png"), "0", "--image", str(tmp_path / "on.png"), "2400", "--assembly", str(assembly),
                 "--pixel-size", "2.5e-4", "--base", *base, "--write", str(target)])
    assert code == 0, capsys.readouterr()
    calibration = load_block_calibration(target)
    assert set(calibration.blocks) == {"SB-1", "SB-2", "SB-3", "SB-77"}
    assert calibration.offset_for("SB-1", 36) == pytest.approx(math.radians(-1.5), abs=math.radians(0.3))
    assert target.read_text().startswith("# Per-block calibration")
    assert yaml.safe_load(target.read_text())["blocks"]["SB-77"]["offset_rad"] == 0.01


def test_errors_exit_2_with_the_problem_named(tmp_path, capsys, assembly):
    (tmp_path / "blank.png").write_bytes(b"")
    code = main(["estimate", str(tmp_path / "blank.png"), "--assembly", str(assembly), "--pixel-size", "2.5e-4",
                 "--base", "0.01", "0.01", "0"])
    assert code == 2 and "cannot read image" in capsys.readouterr().err
    code = main(["render", "--assembly", str(assembly), "--pixel-size", "2.5e-4", "--offset", "7=1", "--out", str(tmp_path / "x.png")])
    assert code == 2 and "block 7 is not in 1..3" in capsys.readouterr().err
    code = main(["calibrate", "--image", "image.png", "0", "--assembly", str(tmp_path / "missing.yaml"), "--pixel-size", "2.5e-4",
                 "--base", "0", "0", "0"])
    assert code == 2 and "cannot read assembly file" in capsys.readouterr().err
    code = main(["calibrate", "--image", "image.png", "-3", "--assembly", str(assembly), "--pixel-size", "2.5e-4",
                 "--base", "0", "0", "0"])
    assert code == 2 and "the voltage must be a number >= 0 V, got '-3'" in capsys.readouterr().err


def test_the_module_runs_as_a_program():
    completed = subprocess.run([sys.executable, "-m", "estimation", "--help"], capture_output=True, text=True, timeout=60)
    assert completed.returncode == 0 and "estimate" in completed.stdout and "calibrate" in completed.stdout
