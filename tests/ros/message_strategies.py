"""Hypothesis strategies for ROS messages, built from a message class's own field types (rosidl SLOT_TYPES).

    messages(SetAssembly.Request, assembly=...)   # every other field drawn from its type

Numbers include NaN, infinities and the extremes of their type; strings are short text; sequences are
short lists (uint8 sequences: bytes). Keyword arguments replace the strategy of a field by name, to steer
the draws toward what a node actually reads.
"""
from __future__ import annotations

import importlib

from hypothesis import strategies as st
from rosidl_parser import definition

MAX_LENGTH = 4  # elements of a drawn sequence
TEXT = st.text(st.characters(exclude_categories=("Cs",)), max_size=20)  # ROS strings are UTF-8
INTEGER_BOUNDS = {
    "int8": (-2**7, 2**7 - 1), "uint8": (0, 2**8 - 1), "int16": (-2**15, 2**15 - 1),
    "uint16": (0, 2**16 - 1), "int32": (-2**31, 2**31 - 1), "uint32": (0, 2**32 - 1),
    "int64": (-2**63, 2**63 - 1), "uint64": (0, 2**64 - 1), "octet": (0, 255), "char": (0, 255),
}


def _basic(type_name: str):
    if type_name in ("double", "long double"):
        return st.floats()
    if type_name == "float":
        return st.floats(width=32)
    if type_name == "boolean":
        return st.booleans()
    low, high = INTEGER_BOUNDS[type_name]
    return st.integers(low, high)


def _class(namespaced: definition.NamespacedType):
    return getattr(importlib.import_module(".".join(namespaced.namespaces)), namespaced.name)


def _strategy(slot):
    if isinstance(slot, definition.BasicType):
        return _basic(slot.typename)
    if isinstance(slot, definition.AbstractGenericString):
        return TEXT
    if isinstance(slot, definition.NamespacedType):
        return st.deferred(lambda: messages(_class(slot)))
    if isinstance(slot, definition.Array):
        return st.lists(_strategy(slot.value_type), min_size=slot.size, max_size=slot.size)
    if isinstance(slot, definition.AbstractSequence):
        if isinstance(slot.value_type, definition.BasicType) and slot.value_type.typename in ("uint8", "octet"):
            return st.binary(max_size=MAX_LENGTH)
        return st.lists(_strategy(slot.value_type), max_size=MAX_LENGTH)
    raise TypeError(f"no strategy for the field type {slot!r}")


def messages(msg_type, **fields):
    """Instances of ``msg_type`` with every field drawn from its type, or from ``fields[name]``."""
    names = list(msg_type.get_fields_and_field_types())
    unknown = set(fields) - set(names)
    if unknown:
        raise ValueError(f"{msg_type.__name__} has no fields {sorted(unknown)}")
    strategies = {name: fields.get(name, _strategy(slot)) for name, slot in zip(names, msg_type.SLOT_TYPES)}
    return st.builds(msg_type, **strategies)
