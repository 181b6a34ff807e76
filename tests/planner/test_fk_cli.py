"""`python -m planner fk`: JSON in SI units, 3D drawing, bad arguments."""
import json
import math
from pathlib import Path

import pytest

from planner.cli import main

pytestmark = pytest.mark.fast

ASSEMBLIES = Path(__file__).resolve().parents[2] / "config" / "assemblies"


def test_fk_writes_json_and_png(tmp_path, capsys):
    out, png = tmp_path / "worm.json", tmp_path / "worm.png"
    code = main(["fk", str(ASSEMBLIES / "figure2_worm.yaml"), "--voltage", "main=1000", "--json", str(out), "--png", str(png)])
    assert code == 0
    data = json.loads(out.read_text())
    chain = data["chains"][0]
    assert data["assembly"] == "figure2_worm" and chain["voltage_V"] == 1000.0
    blocks = chain["blocks"]
    assert [b["id"] for b in blocks] == [15] * 4
    assert [b["phi_rad"] for b in blocks] == pytest.approx([0.0, math.pi, math.pi, math.pi])
    assert all(b["valid"] and 0 < b["theta_rad"] < 1 and b["rod_length_m"] == 0.015 for b in blocks)
    assert blocks[-1]["end_position_m"] == pytest.approx(chain["centerline_m"][-1])
    assert blocks[1]["end_position_m"][0] == pytest.approx(2 * blocks[0]["end_position_m"][0])
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"
    printed = capsys.readouterr().out
    assert "worm (channel main, 1000 V)" in printed and "theta[deg]" in printed


def test_fk_rejects_unknown_channels_and_bad_voltages(capsys):
    assert main(["fk", str(ASSEMBLIES / "legged.yaml"), "--voltage", "trunk=100"]) == 2
    assert "no channel ['trunk']" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["fk", str(ASSEMBLIES / "legged.yaml"), "--voltage", "leg_front_left"])
    assert "CHANNEL=VOLTS" in capsys.readouterr().err


@pytest.mark.parametrize("block, problem", [
    ("{id: true}", "design_id must be a positive integer, got True"),
    ("{id: 15, rotaton_steps: 3}", "block 0: unknown key(s) ['rotaton_steps']"),
])
def test_fk_refuses_a_bool_id_and_misspelt_keys_naming_them(tmp_path, capsys, block, problem):
    path = tmp_path / "typo.yaml"
    path.write_text(f"name: typo\nchains:\n  - {{name: arm, hv_channel: main, blocks: [{block}]}}\n")
    assert main(["fk", str(path)]) == 2
    error = capsys.readouterr().err
    assert problem in error and "chain 'arm'" in error and error.count("\n") == 1
