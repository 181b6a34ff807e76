"""Manipulation sequences as data: the YAML schema, its loader and validation (no ROS).

A sequence file names the HV channels it drives and lists steps. Each step is a mapping with a
``name`` and exactly one kind key (``move_arm``, ``ramp``, ``wait``, ``parallel``, ``pulse_train``,
``operator_swap``)
plus optional ``description``, ``precondition``, ``timeout`` and ``on_failure``. See docs/sequences.md.

Every problem raises `SequenceError` (a ValueError) whose message names the step and the field,
e.g. ``step 'open_back' (steps[1]): ramp.target=3000: above the voltage ceiling 2500 V``.

Sequence files come from clients by name, so reading them is bounded: a goal names a file in the
sequence directory (no paths, no links out of it); the file's size, its nesting depth and the length
of any value quoted in an error are limited, and YAML anchors and aliases are refused (they let a
1 KB file expand to gigabytes or refer to itself).
"""
from __future__ import annotations

import math
import re
import reprlib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

from hv_driver.pulse import EDGES as PULSE_EDGES
from hv_driver.ramp import MIN_JERK_PEAK_RATE
from planner.bounded_yaml import YAMLInputError, load_yaml_file

ON_FAILURE = ("safe_stop", "estop")  # ramp every channel to 0 V (e-stop if that fails) | e-stop at once
STEP_KINDS = ("move_arm", "ramp", "wait", "parallel", "pulse_train", "operator_swap")
ROTATION_STEPS = 12         # a block snaps in at 30 deg steps
OPERATOR_TIMEOUT_S = 600.0  # an operator_swap's default timeout: a person swaps blocks
COMMON_KEYS = {"name", "description", "precondition", "timeout", "on_failure"}
_NAME = re.compile(r"^[A-Za-z0-9_\-]+$")
MAX_FILE_SIZE = 256 * 1024  # [bytes]; the shipped sequences are below 10 KB
MAX_NAME_LENGTH = 100       # characters of a sequence name in a goal
MAX_EXCERPT = 80            # characters of a value quoted in an error message
_EXCERPT = reprlib.Repr()
_EXCERPT.maxstring, _EXCERPT.maxother, _EXCERPT.maxlevel = MAX_EXCERPT, MAX_EXCERPT, 3


class SequenceError(ValueError):
    """A sequence file that cannot be run; the message names the step and the field."""


def excerpt(value) -> str:
    """repr of ``value`` cut to MAX_EXCERPT characters (reprlib: never builds the repr of a huge value)."""
    text = _EXCERPT.repr(value)
    return text if len(text) <= MAX_EXCERPT else text[:MAX_EXCERPT - 3] + "..."


@dataclass(frozen=True)
class Limits:
    """What the hardware allows; sequences beyond it are rejected before anything moves.

    voltage_ceiling_v: highest voltage any step may command [V].
    max_pulse_frequency_hz: highest pulse-train frequency [Hz] (the paper's legs run up to 5 Hz).
    max_slew_rate_v_per_s: the HV driver's slew limit [V/s]; None = not checked here (the driver refuses).
    """

    voltage_ceiling_v: float = 2500.0
    max_pulse_frequency_hz: float = 5.0
    max_slew_rate_v_per_s: float | None = None


@dataclass(frozen=True)
class StepDefaults:
    """Values of the steps that give none; a file's ``defaults`` and the sequencer's parameters override them."""

    timeout_s: float = 30.0
    tolerance_v: float = 50.0
    speed_m_per_s: float = 0.0      # 0 = the arm's default
    slew_rate_v_per_s: float = 0.0  # 0 = the driver's configured rate
    frame_id: str = "base_link"
    on_failure: str = "safe_stop"


# A file's `defaults:` keys (the step keys they stand for) and the StepDefaults fields they set.
DEFAULT_FIELDS = {"timeout": "timeout_s", "tolerance": "tolerance_v", "speed": "speed_m_per_s",
                  "slew_rate": "slew_rate_v_per_s", "frame_id": "frame_id", "on_failure": "on_failure"}
DEFAULTS = {key: getattr(StepDefaults(), name) for key, name in DEFAULT_FIELDS.items()}


@dataclass(frozen=True)
class Precondition:
    """What must hold before a step starts: channel voltages within ``tolerance`` (no HV fault is always required)."""

    voltages: Mapping[str, float] = field(default_factory=dict)  # channel -> expected voltage [V]
    tolerance: float = StepDefaults.tolerance_v                   # [V]


@dataclass(frozen=True, kw_only=True)
class Step:
    name: str
    description: str = ""
    precondition: Precondition = Precondition()
    timeout: float = StepDefaults.timeout_s  # [s]
    on_failure: str = "safe_stop"


@dataclass(frozen=True, kw_only=True)
class MoveArmStep(Step):
    position: tuple[float, float, float]                 # [m]
    orientation: tuple[float, float, float, float]       # quaternion (x, y, z, w)
    frame_id: str
    speed: float = 0.0                                   # [m/s]; 0 = the arm's default


@dataclass(frozen=True, kw_only=True)
class RampStep(Step):
    channel: str
    target: float                # [V]
    slew_rate: float = 0.0       # [V/s]; 0 = the driver's configured rate
    duration: float | None = None  # [s]; alternative to slew_rate, converted at run time
    tolerance: float = 50.0      # reached-target tolerance [V]


@dataclass(frozen=True, kw_only=True)
class WaitStep(Step):
    duration: float  # [s]


@dataclass(frozen=True, kw_only=True)
class ParallelStep(Step):
    steps: tuple[Step, ...]


@dataclass(frozen=True, kw_only=True)
class PulseTrainStep(Step):
    """Channels switched on (``voltage``) and off (0 V) together, ``cycles`` times at ``frequency``.

    Within each period the output is on for the fraction ``duty``; ``phase`` (fraction of a period)
    delays the train, so two trains in a ``parallel`` step make an alternating gait. ``edge`` "smooth":
    minimum-jerk edges at ``slew_rate``, generated in the HV driver's loop; "square": the supply switches
    itself (e.g. a Peta-pico-Voltron; ``slew_rate`` unused).
    """

    channels: tuple[str, ...]
    voltage: float      # [V]
    frequency: float    # [Hz]
    duty: float         # 0 < duty < 1
    cycles: int
    slew_rate: float    # [V/s]
    phase: float = 0.0
    tolerance: float = 50.0
    edge: str = "smooth"

    @property
    def ramp_time(self) -> float:
        """Duration of one on or off edge with the driver's minimum-jerk ramp [s]."""
        return MIN_JERK_PEAK_RATE * self.voltage / self.slew_rate

    @property
    def length(self) -> float:
        """Scheduled length of the whole train [s]."""
        return (self.cycles + self.phase) / self.frequency


@dataclass(frozen=True)
class Swap:
    """One block the operator changes; ``position`` 0 is the block at the chain's base (as in the planner's
    ``SwapStep``). ``remove`` or ``insert`` is None when a position is emptied now and filled later."""

    chain: str
    position: int
    remove: int | None
    insert: int | None
    rotation_steps: int = 0

    def describe(self) -> str:
        what = [f"remove design {self.remove}"] if self.remove is not None else []
        if self.insert is not None:
            what.append(f"insert design {self.insert} at rotation step {self.rotation_steps}")
        return f"finger {self.chain}, position {self.position}: " + ", ".join(what)


@dataclass(frozen=True, kw_only=True)
class OperatorSwapStep(Step):
    """The operator swaps blocks with every channel at 0 V, confirms, and the camera estimator must then find
    ``assembly`` as built before the sequence goes on."""

    assembly: str               # name of the assembly after the swaps
    swaps: tuple[Swap, ...] = ()

    def prompt(self) -> str:
        swaps = "; ".join(swap.describe() for swap in self.swaps) or "check the blocks"
        return f"build assembly {self.assembly!r}: {swaps}"


@dataclass(frozen=True)
class Sequence:
    name: str
    description: str
    channels: tuple[str, ...]
    steps: tuple[Step, ...]
    source: str = ""  # file it was loaded from

    def step_count(self) -> int:
        return len(self.steps)


class _Where:
    """Location of a step for error messages: ``step 'name' (steps[2].parallel[0])``."""

    def __init__(self, path: str, name: str | None = None):
        self.path, self.name = path, name

    def fail(self, field_name: str, value, expectation: str):
        label = f"step {self.name!r} ({self.path})" if self.name else self.path
        shown = "(missing)" if value is _MISSING else excerpt(value)
        raise SequenceError(f"{label}: {field_name}={shown}: {expectation}")


_MISSING = object()


def _number(where: _Where, spec: Mapping, key: str, field_name: str, default=_MISSING, *,
            minimum: float | None = None, exclusive_minimum: float | None = None,
            maximum: float | None = None) -> float:
    value = spec.get(key, default)
    if value is _MISSING:
        where.fail(field_name, value, "required")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        where.fail(field_name, value, "a finite number")
    if minimum is not None and value < minimum:
        where.fail(field_name, value, f"must be >= {minimum:g}")
    if exclusive_minimum is not None and value <= exclusive_minimum:
        where.fail(field_name, value, f"must be > {exclusive_minimum:g}")
    if maximum is not None and value > maximum:
        where.fail(field_name, value, f"must be <= {maximum:g}")
    return float(value)


def _integer(where: _Where, spec: Mapping, key: str, field_name: str, minimum: int, maximum: int | None = None,
             default=_MISSING):
    value = spec.get(key, default)
    if value is None and default is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum or (maximum is not None
                                                                                   and value > maximum):
        bound = f"between {minimum} and {maximum}" if maximum is not None else f">= {minimum}"
        where.fail(field_name, value, f"an integer {bound}" + (" or null" if default is None else ""))
    return value


def _vector(where: _Where, spec: Mapping, key: str, field_name: str, length: int) -> tuple[float, ...]:
    value = spec.get(key, _MISSING)
    if (not isinstance(value, (list, tuple)) or len(value) != length
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        where.fail(field_name, value, f"a list of {length} finite numbers")
    return tuple(float(v) for v in value)


def _mapping(where: _Where, value, field_name: str, allowed: set[str]) -> Mapping:
    if not isinstance(value, Mapping):
        where.fail(field_name, value, "a mapping")
    unknown = sorted(set(value) - allowed)
    if unknown:
        where.fail(field_name, dict(value), f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    return value


class _Parser:
    def __init__(self, channels: tuple[str, ...], defaults: Mapping, limits: Limits):
        self.channels, self.defaults, self.limits = channels, defaults, limits

    def channel(self, where: _Where, value, field_name: str) -> str:
        if not isinstance(value, str) or value not in self.channels:
            where.fail(field_name, value, f"a channel declared in `channels` {list(self.channels)}")
        return value

    def voltage(self, where: _Where, spec: Mapping, key: str, field_name: str) -> float:
        ceiling = self.limits.voltage_ceiling_v
        value = _number(where, spec, key, field_name, minimum=0.0)
        if value > ceiling:
            where.fail(field_name, spec[key], f"above the voltage ceiling {ceiling:g} V")
        return value

    def slew_rate(self, where: _Where, spec: Mapping, field_name: str, default) -> float:
        value = _number(where, spec, "slew_rate", field_name, default, minimum=0.0)
        limit = self.limits.max_slew_rate_v_per_s
        if limit is not None and value > limit:
            where.fail(field_name, spec["slew_rate"], f"above the HV driver's slew limit {limit:g} V/s")
        return value

    def steps(self, items, path: str) -> tuple[Step, ...]:
        if not isinstance(items, list) or not items:
            _Where(path).fail("steps", items, "a non-empty list of steps")
        steps = tuple(self.step(item, f"{path}[{index}]") for index, item in enumerate(items))
        seen = set()
        for step in steps:
            if step.name in seen:
                _Where(path, step.name).fail("name", step.name, "used twice; step names must be unique")
            seen.add(step.name)
        return steps

    def step(self, spec, path: str) -> Step:
        where = _Where(path)
        if not isinstance(spec, Mapping):
            where.fail("step", spec, "a mapping with a name and one step kind")
        name = spec.get("name", _MISSING)
        if not isinstance(name, str) or not _NAME.match(name):
            where.fail("name", name, "a name of letters, digits, '_' or '-'")
        where = _Where(path, name)
        kinds = [key for key in spec if key in STEP_KINDS]
        unknown = sorted(set(spec) - COMMON_KEYS - set(STEP_KINDS))
        if unknown:
            where.fail("kind", unknown[0], f"unknown step kind or key; step kinds are {list(STEP_KINDS)}")
        if len(kinds) != 1:
            where.fail("kind", kinds, f"exactly one step kind of {list(STEP_KINDS)}")
        kind = kinds[0]
        description = spec.get("description", "")
        if not isinstance(description, str):
            where.fail("description", description, "a string")
        on_failure = spec.get("on_failure", self.defaults.get("on_failure", "safe_stop"))
        if on_failure not in ON_FAILURE:
            where.fail("on_failure", on_failure, f"one of {list(ON_FAILURE)}")
        common = dict(name=name, description=description, on_failure=on_failure,
                      precondition=self.precondition(where, spec.get("precondition", {})))
        body = getattr(self, kind)(where, spec[kind], common)
        live = {channel: v for channel, v in body.precondition.voltages.items() if v != 0}
        if kind == "operator_swap" and live:
            channel = next(iter(live))
            where.fail(f"precondition.voltages.{channel}", live[channel], "an operator_swap needs every channel at 0 V")
        timeout = _number(where, spec, "timeout", "timeout", body.timeout, exclusive_minimum=0.0)
        if timeout < body.timeout and kind in ("wait", "pulse_train"):
            where.fail("timeout", timeout, f"shorter than the step itself ({body.timeout:g} s)")
        return replace(body, timeout=timeout)

    def precondition(self, where: _Where, spec) -> Precondition:
        spec = _mapping(where, spec, "precondition", {"voltages", "tolerance"})
        voltages = spec.get("voltages", {})
        if not isinstance(voltages, Mapping):
            where.fail("precondition.voltages", voltages, "a mapping channel -> voltage [V]")
        expected = {}
        for channel in voltages:
            self.channel(where, channel, f"precondition.voltages.{channel}")
            expected[channel] = self.voltage(where, voltages, channel, f"precondition.voltages.{channel}")
        tolerance = _number(where, spec, "tolerance", "precondition.tolerance", self.defaults["tolerance"],
                            exclusive_minimum=0.0)
        return Precondition(expected, tolerance)

    def move_arm(self, where: _Where, spec, common) -> MoveArmStep:
        spec = _mapping(where, spec, "move_arm", {"position", "orientation", "speed", "frame_id"})
        orientation = _vector(where, spec, "orientation", "move_arm.orientation", 4)
        if abs(math.sqrt(sum(v * v for v in orientation)) - 1.0) > 1e-3:
            where.fail("move_arm.orientation", list(orientation), "a unit quaternion (x, y, z, w)")
        frame_id = spec.get("frame_id", self.defaults["frame_id"])
        if not isinstance(frame_id, str) or not frame_id:
            where.fail("move_arm.frame_id", frame_id, "a non-empty frame name")
        return MoveArmStep(**common, position=_vector(where, spec, "position", "move_arm.position", 3),
                           orientation=orientation, frame_id=frame_id,
                           speed=_number(where, spec, "speed", "move_arm.speed", self.defaults["speed"], minimum=0.0),
                           timeout=self.defaults["timeout"])

    def ramp(self, where: _Where, spec, common) -> RampStep:
        spec = _mapping(where, spec, "ramp", {"channel", "target", "slew_rate", "duration", "tolerance"})
        if "slew_rate" in spec and "duration" in spec:
            where.fail("ramp.duration", spec["duration"], "give either slew_rate or duration, not both")
        duration = None
        if "duration" in spec:
            duration = _number(where, spec, "duration", "ramp.duration", exclusive_minimum=0.0)
        return RampStep(**common, channel=self.channel(where, spec.get("channel", _MISSING), "ramp.channel"),
                        target=self.voltage(where, spec, "target", "ramp.target"),
                        slew_rate=self.slew_rate(where, spec, "ramp.slew_rate", self.defaults["slew_rate"]),
                        duration=duration,
                        tolerance=_number(where, spec, "tolerance", "ramp.tolerance", self.defaults["tolerance"],
                                          exclusive_minimum=0.0),
                        timeout=self.defaults["timeout"])

    def wait(self, where: _Where, spec, common) -> WaitStep:
        spec = _mapping(where, spec, "wait", {"duration"})
        duration = _number(where, spec, "duration", "wait.duration", minimum=0.0)
        return WaitStep(**common, duration=duration, timeout=duration + self.defaults["timeout"])

    def parallel(self, where: _Where, spec, common) -> ParallelStep:
        steps = self.steps(spec, f"{where.path}.parallel")
        for index, step in enumerate(steps):
            if isinstance(step, OperatorSwapStep):  # a sibling could energise a channel during the swap
                where.fail(f"parallel[{index}].operator_swap", step.name, "not allowed in a parallel step")
        return ParallelStep(**common, steps=steps, timeout=max(step.timeout for step in steps))

    def pulse_train(self, where: _Where, spec, common) -> PulseTrainStep:
        spec = _mapping(where, spec, "pulse_train", {"channels", "voltage", "frequency", "duty", "cycles",
                                                     "phase", "slew_rate", "tolerance", "edge"})
        channels = spec.get("channels", _MISSING)
        if not isinstance(channels, list) or not channels:
            where.fail("pulse_train.channels", channels, "a non-empty list of channels")
        for index, channel in enumerate(channels):
            self.channel(where, channel, f"pulse_train.channels[{index}]")
        cycles = spec.get("cycles", _MISSING)
        if isinstance(cycles, bool) or not isinstance(cycles, int) or cycles < 1:
            where.fail("pulse_train.cycles", cycles, "an integer >= 1")
        edge = spec.get("edge", "smooth")
        if edge not in PULSE_EDGES:
            where.fail("pulse_train.edge", edge, f"one of {', '.join(PULSE_EDGES)}")
        step = PulseTrainStep(
            **common, channels=tuple(channels), cycles=cycles,
            voltage=self.voltage(where, spec, "voltage", "pulse_train.voltage"),
            frequency=_number(where, spec, "frequency", "pulse_train.frequency", exclusive_minimum=0.0,
                              maximum=self.limits.max_pulse_frequency_hz),
            duty=_number(where, spec, "duty", "pulse_train.duty", exclusive_minimum=0.0, maximum=0.999),
            phase=_number(where, spec, "phase", "pulse_train.phase", 0.0, minimum=0.0, maximum=0.999),
            slew_rate=self.slew_rate(where, spec, "pulse_train.slew_rate", _MISSING if edge == "smooth" else 0.0),
            edge=edge,
            tolerance=_number(where, spec, "tolerance", "pulse_train.tolerance", self.defaults["tolerance"],
                              exclusive_minimum=0.0),
            timeout=1.0)
        if edge == "square":  # the supply's own edges: it checks what it can switch when the train is sent
            return replace(step, timeout=step.length + self.defaults["timeout"])
        if step.slew_rate == 0:
            where.fail("pulse_train.slew_rate", 0, "must be > 0 (the edges must fit the on/off times)")
        shortest_phase = min(step.duty, 1.0 - step.duty) / step.frequency
        if step.ramp_time > shortest_phase:
            where.fail("pulse_train.slew_rate", step.slew_rate,
                       f"too slow: an edge takes {step.ramp_time * 1e3:.0f} ms "
                       f"({MIN_JERK_PEAK_RATE:g} x voltage / slew_rate) but the shortest on/off phase "
                       f"is {shortest_phase * 1e3:.0f} ms")
        return replace(step, timeout=step.length + self.defaults["timeout"])

    def operator_swap(self, where: _Where, spec, common) -> OperatorSwapStep:
        spec = _mapping(where, spec, "operator_swap", {"assembly", "swaps"})
        assembly = spec.get("assembly", _MISSING)
        if not isinstance(assembly, str) or not assembly.strip():
            where.fail("operator_swap.assembly", assembly, "the name of the assembly after the swaps")
        items = spec.get("swaps", [])
        if not isinstance(items, list):
            where.fail("operator_swap.swaps", items, "a list of swaps (chain, position, remove, insert, rotation_steps)")
        swaps, seen = [], set()
        for index, item in enumerate(items):
            label = f"operator_swap.swaps[{index}]"
            item = _mapping(where, item, label, {"chain", "position", "remove", "insert", "rotation_steps"})
            chain = item.get("chain", _MISSING)
            if not isinstance(chain, str) or not chain:
                where.fail(f"{label}.chain", chain, "a chain name")
            swap = Swap(chain, _integer(where, item, "position", f"{label}.position", 0),
                        _integer(where, item, "remove", f"{label}.remove", 1, default=None),
                        _integer(where, item, "insert", f"{label}.insert", 1, default=None),
                        _integer(where, item, "rotation_steps", f"{label}.rotation_steps", 0, ROTATION_STEPS - 1, 0))
            if swap.remove is None and swap.insert is None:
                where.fail(f"{label}.insert", None, "give remove, insert or both")
            if (swap.chain, swap.position, swap.insert is None) in seen:
                where.fail(f"{label}.position", swap.position, f"swapped twice in chain {swap.chain!r}")
            seen.add((swap.chain, swap.position, swap.insert is None))
            swaps.append(swap)
        return OperatorSwapStep(**common, assembly=assembly, swaps=tuple(swaps), timeout=OPERATOR_TIMEOUT_S)


def parse_sequence(document, limits: Limits = Limits(), source: str = "", defaults: Mapping | None = None) -> Sequence:
    """Validate a sequence given as parsed YAML (a mapping) and return it; SequenceError otherwise.

    defaults: site-wide step defaults (keys of DEFAULTS) under the file's own ``defaults``.
    """
    top = _Where(source or "sequence")
    if not isinstance(document, Mapping):  # e.g. a text file: say what it is, not what it says
        raise SequenceError(f"{top.path}: a sequence file is a mapping (name, channels, steps), "
                            f"not a {type(document).__name__}")
    document = _mapping(top, document, "sequence", {"name", "description", "channels", "defaults", "steps"})
    name = document.get("name", _MISSING)
    if not isinstance(name, str) or not _NAME.match(name):
        top.fail("name", name, "a name of letters, digits, '_' or '-'")
    channels = document.get("channels", _MISSING)
    if (not isinstance(channels, list) or not channels or not all(isinstance(c, str) and c for c in channels)
            or len(set(channels)) != len(channels)):
        top.fail("channels", channels, "a non-empty list of distinct HV channel names")
    file_defaults = _mapping(top, document.get("defaults", {}), "defaults", set(DEFAULTS))
    merged = {**DEFAULTS, **(defaults or {}), **file_defaults}
    for key in ("timeout", "tolerance", "speed", "slew_rate"):
        _number(top, merged, key, f"defaults.{key}", minimum=0.0)
    parser = _Parser(tuple(channels), merged, limits)
    return Sequence(name=name, description=str(document.get("description", "")), channels=tuple(channels),
                    steps=parser.steps(document.get("steps", _MISSING), "steps"), source=source)


def load_sequence_file(path: str | Path, limits: Limits = Limits(), defaults: Mapping | None = None) -> Sequence:
    """Read (bounded, see the module docstring) and validate one sequence file; SequenceError otherwise."""
    path = Path(path)
    try:
        document = load_yaml_file(path, MAX_FILE_SIZE)
    except YAMLInputError as error:
        raise SequenceError(str(error)) from None
    return parse_sequence(document, limits, source=str(path), defaults=defaults)


def resolve_sequence_path(sequence: str, sequences_dir: str | Path) -> Path:
    """``<sequences_dir>/<sequence>.yaml`` for a sequence name; never a file outside the directory.

    A name is letters, digits, '_' and '-': no paths, no '..'. A file that is a link out of the directory
    is refused too. SequenceError otherwise (naming the sequences there when the name is unknown).
    """
    directory = Path(sequences_dir).resolve()
    if not isinstance(sequence, str) or not sequence.strip():
        raise SequenceError(f"sequence={excerpt(sequence)}: give a sequence name")
    if len(sequence) > MAX_NAME_LENGTH or not _NAME.match(sequence):
        raise SequenceError(f"sequence={excerpt(sequence)}: a sequence name is up to {MAX_NAME_LENGTH} letters, "
                            f"digits, '_' or '-' (no paths); it names <name>.yaml in {sequences_dir}")
    path = directory / f"{sequence}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in directory.glob("*.yaml")) if directory.is_dir() else []
        raise SequenceError(f"sequence={sequence!r}: no such file {path} (sequences in {sequences_dir}: {known})")
    if not path.resolve().is_relative_to(directory):
        raise SequenceError(f"sequence={sequence!r}: {path} links outside {sequences_dir}; refused")
    return path


def load_sequence(sequence: str, sequences_dir: str | Path, limits: Limits = Limits(),
                  defaults: Mapping | None = None) -> Sequence:
    """Load and validate a sequence by name from ``sequences_dir``; SequenceError names the file, step and field."""
    return load_sequence_file(resolve_sequence_path(sequence, sequences_dir), limits, defaults)
