"""Python message classes for ROS type names, found by importing `pkg.msg`."""
import importlib


class UnknownMessageTypeError(LookupError):
    """A recorded type has no importable Python message class here."""


def import_message_type(type_name: str, topic: str = ""):
    """The class for 'pkg/msg/Type'; UnknownMessageTypeError names the type (and topic)."""
    where = f" (topic {topic})" if topic else ""
    parts = type_name.split("/")
    if len(parts) != 3 or parts[1] != "msg":
        raise UnknownMessageTypeError(
            f"message type {type_name!r}{where} is not of the form 'pkg/msg/Type'")
    package, kind, name = parts
    try:
        return getattr(importlib.import_module(f"{package}.{kind}"), name)
    except (ImportError, AttributeError) as error:
        raise UnknownMessageTypeError(
            f"message type {type_name}{where} cannot be imported as {package}.{kind}.{name}: "
            f"{error}; install or source the package that defines it") from error
