"""The two-host stack's reading of the driver's own hv/state stamps (no root needed)."""
import pytest

from hv_driver.supervisor import DEFAULT_PERIOD_S, SLEW_CREDIT_PERIODS
from netlab.stack import STALL_S, driver_stalls

pytestmark = pytest.mark.fast

CREDIT_S = SLEW_CREDIT_PERIODS * DEFAULT_PERIOD_S


def samples(stamps, first_sequence=100):
    return [{"type": "state", "stamp": stamp, "sequence": first_sequence + index} for index, stamp in enumerate(stamps)]


def every_20_ms(start, end):
    return [start + 0.02 * k for k in range(round((end - start) / 0.02) + 1)]


def test_a_partition_whose_driver_stalled_gets_the_stall_added_to_its_bound():
    # A fresh-clone run: the driver sent nothing from 5.602 s to 7.194 s after the cut and had every channel below
    # 50 V after 7.24 s, past heartbeat timeout + ramp time (6.41 s); its ramp resumed where it had stopped.
    states = samples(every_20_ms(0.002, 5.602) + every_20_ms(7.194, 7.294))
    stalls = driver_stalls(states, since=0.0, until=7.262)
    assert stalls == [pytest.approx(7.194 - 5.602 - CREDIT_S)]
    assert 7.24 <= 6.41 + sum(stalls)


def test_only_gaps_of_the_driver_itself_longer_than_a_stall_count_within_the_window():
    late_cycle = every_20_ms(0.0, 1.0) + every_20_ms(0.99 + STALL_S, 2.0)   # 90 ms: a late cycle, not a stall
    lost = every_20_ms(2.5, 3.0)   # 2.0 -> 2.5 s: the sample before 2.5 s was lost on the way (below), not a stall
    stall = every_20_ms(3.5, 4.0)  # 3.0 -> 3.5 s: a stall
    states = samples(late_cycle + lost + stall)
    del states[len(late_cycle) - 1]
    assert driver_stalls(states, since=0.0, until=4.0) == [pytest.approx(0.5 - CREDIT_S)]
    assert driver_stalls(states, since=3.2, until=4.0) == []   # the stall began before the window
    assert driver_stalls(states, since=0.0, until=3.4) == []   # ... or ended after it
    assert driver_stalls(list(reversed(states)), since=0.0, until=4.0) == [pytest.approx(0.5 - CREDIT_S)]
