"""A reconfiguration plan's operator steps (``planner.reconfigure.swap_steps``) as an ``operator_swap`` step of a
sequence file: the operator makes the swaps with every channel at 0 V, and the camera estimator must find the
plan's assembly as built before the sequence goes on (docs/reconfiguration.md)."""
from __future__ import annotations

from collections.abc import Iterable

from planner.reconfigure import SwapStep


def operator_swap_step(name: str, assembly: str, steps: Iterable[SwapStep], timeout_s: float | None = None) -> dict:
    """The sequence-file mapping of one ``operator_swap`` step doing ``steps`` to build ``assembly``."""
    swaps = [{"chain": step.chain, "position": step.position, "remove": step.remove, "insert": step.insert,
              "rotation_steps": step.rotation_steps} for step in steps]
    step = {"name": name, "operator_swap": {"assembly": assembly, "swaps": swaps}}
    if timeout_s is not None:
        step["timeout"] = timeout_s
    return step
