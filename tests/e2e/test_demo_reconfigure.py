"""The second demo end to end: `python -m softblock_ros.demo_reconfigure` on the simulated backend. The strawberry
gripper is planned into the asymmetric-object gripper, one swap is done wrong and must be caught by the camera
before any channel is energised, then the correction lets the new front fingers close at 2.4 kV."""
import json
import sys

import pytest
from processes import run

# stack: `make test` runs it after the other tiers, beside another stack module (tests/conftest.py)
pytestmark = pytest.mark.stack

DEMO_TIMEOUT = 300.0  # [s] liveness bound only; the demo takes about a minute on an idle 2-core machine
SWAPS = 4


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("reconfigure")
    demo_run = run([sys.executable, "-m", "softblock_ros.demo_reconfigure", "--out", str(out),
                    "--swaps", str(SWAPS)], timeout=DEMO_TIMEOUT)
    return demo_run, out


def test_the_demo_exits_zero_and_writes_its_outputs(demo):
    demo_run, out = demo
    assert demo_run.returncode == 0, demo_run.stdout[-3000:] + demo_run.stderr[-3000:]
    for name in ("pareto.png", "recording.png", "run.mcap", "summary.json", "stack.log",
                 "sequences/reconfigure.yaml", "sequences/correct_swap.yaml"):
        assert (out / name).stat().st_size > 0, name


def test_the_plan_stays_within_its_budget_and_every_point_carries_its_bound(demo):
    _, out = demo
    summary = json.loads((out / "summary.json").read_text())
    points = summary["plan"]["points"]
    assert [p["max_swaps"] for p in points] == list(range(9))  # the front pair: 8 blocks
    chosen = points[SWAPS]
    assert 1 <= chosen["swaps"] <= SWAPS and len(summary["plan"]["swaps"]) == chosen["swaps"]
    assert all(p["lower_bound_m"] <= p["objective_m"] + 1e-9 for p in points)


def test_the_wrong_swap_is_caught_before_any_channel_is_energised(demo):
    _, out = demo
    summary = json.loads((out / "summary.json").read_text())
    wrong, run_1 = summary["wrong_swap"], summary["wrong_run"]
    assert not run_1["success"] and run_1["failed_step"] == "swap"
    assert f"chain {wrong['chain']}: block {wrong['position'] + 1}:" in run_1["message"]
    assert "the HV outputs stay off until a swap is verified" in run_1["message"]
    assert run_1["peak_voltage_v"] < 50.0


def test_the_corrected_gripper_is_verified_then_energised(demo):
    _, out = demo
    run_2 = json.loads((out / "summary.json").read_text())["corrected_run"]
    assert run_2["success"], run_2["message"]
    assert run_2["peak_voltage_v"] == pytest.approx(2400.0, abs=30.0)
