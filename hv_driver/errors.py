"""The driver's errors. Every error it raises on purpose is an `HvError`, so a caller (the ROS node) catches
that one class at its boundary; each is also the matching built-in (ValueError, RuntimeError, ConnectionError)."""


class HvError(Exception):
    """Base of every error the driver raises on purpose."""


class SettingError(HvError, ValueError):
    """A setting or request the driver refuses; the message names the parameter and the allowed values."""


class StateError(HvError, RuntimeError):
    """A request the driver's present state forbids (e.g. a ramp while the output is off)."""
