"""Samples lost between a publisher and the recorder, from the publishers' own sample counters.

The recorder stores each message's DDS publication sequence number in the MCAP message's ``sequence`` field.
A publisher numbers its samples 1, 2, 3, ...; a reliable topic is delivered in that order, so a number that
is skipped is a sample the recorder never got (lost on the network beyond what the QoS repairs, or dropped
by a full history). A number lower than the one before starts a new run: a new publisher (e.g. a restarted
node) counts from 1 again. Only topics with one reliable publisher are checked: several publishers'
counters interleave, and a best-effort topic may arrive out of order.
"""
from __future__ import annotations

from collections.abc import Iterable

from .qos_profiles import parse_offered_qos


def checkable(offered_qos_profiles: str, topic: str = "") -> str:
    """Why a topic's numbers cannot be checked ("" when they can), from its channel's QoS metadata."""
    profiles = parse_offered_qos(offered_qos_profiles, topic)
    if len(profiles) != 1:
        return f"{len(profiles)} publishers when recorded (their counters interleave)"
    if profiles[0].get("reliability") != "reliable":
        return "best-effort publisher (samples may arrive out of order)"
    return ""


def find_gaps(samples: Iterable[tuple[int, int]]) -> dict:
    """Gaps in the (sequence, publish time [ns]) pairs of one topic, in the order received.

    Returns ``received``, ``lost`` (samples missing between the first and last of each run) and ``gaps``:
    for each, the numbers ``after`` and ``before`` it, the publish times around it [ns] and ``lost``.
    Samples without a number (0) are counted as received and otherwise ignored. ``interleaved`` is True when
    the numbers fall back to anything but a new run from 1: a second publisher that joined after the
    recorder subscribed, whose counter interleaves with the first's (its gaps are then meaningless)."""
    received, gaps, interleaved = 0, [], False
    previous: tuple[int, int] | None = None
    for sequence, publish_time in samples:
        received += 1
        if not sequence:
            continue
        if previous is not None and sequence < previous[0] and sequence != 1:
            interleaved = True
        if previous is not None and sequence > previous[0] + 1:
            gaps.append({"after": previous[0], "before": sequence, "lost": sequence - previous[0] - 1,
                         "after_time_ns": previous[1], "before_time_ns": publish_time})
        previous = (sequence, publish_time)
    return {"received": received, "lost": sum(gap["lost"] for gap in gaps), "gaps": gaps, "interleaved": interleaved}
