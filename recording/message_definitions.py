"""Full `ros2msg` message definitions for MCAP schemas, assembled as rosbag2 (Jazzy) does.

The text is the root .msg file verbatim, then every nested type once, depth-first in sorted
order, each behind a line of 80 '=' and a 'MSG: pkg/Type' line. The .msg files are found through
the ament index (AMENT_PREFIX_PATH): the ROS wheels in the venv and the colcon-built ros_ws.
No rclpy import: the analysis side uses this module without ROS running, and imports it without ROS installed
(ament_index_python is imported only when a definition is looked up, i.e. when a recording is written).
"""
import os
import re

SCHEMA_ENCODING = "ros2msg"
DELIMITER = "=" * 80

PRIMITIVE_TYPES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
})

_TYPE_NAME = re.compile(r"^([A-Za-z0-9_]+)/(?:msg/)?([A-Za-z0-9_]+)$")


class DefinitionNotFoundError(LookupError):
    """No .msg file for a message type (not installed, or defined only as .idl)."""


def split_type_name(type_name: str) -> tuple[str, str]:
    """'pkg/msg/Type' or 'pkg/Type' -> ('pkg', 'Type'); ValueError for anything else."""
    match = _TYPE_NAME.match(type_name)
    if match is None:
        raise ValueError(f"type_name {type_name!r} is not of the form 'pkg/msg/Type'")
    return match.group(1), match.group(2)


def find_msg_file(type_name: str) -> str:
    """Path of the .msg file defining `type_name`, looked up in the ament index."""
    package, name = split_type_name(type_name)
    try:
        from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
    except ImportError as error:
        raise DefinitionNotFoundError(
            f"the .msg file of {type_name} is looked up in the ament index, and ament_index_python is not installed "
            "(ROS 2 or its PyPI wheels); reading and analysing recordings does not need it") from error
    try:
        share = get_package_share_directory(package, print_warning=False)
    except PackageNotFoundError as error:
        raise DefinitionNotFoundError(
            f"package {package!r} of {type_name} is not in the ament index "
            f"(AMENT_PREFIX_PATH={os.environ.get('AMENT_PREFIX_PATH', '')!r})") from error
    path = os.path.join(share, "msg", name + ".msg")
    if not os.path.isfile(path):
        raise DefinitionNotFoundError(f"no .msg file for {type_name} (looked for {path})")
    return path


def field_dependencies(msg_text: str, package: str) -> list[str]:
    """Non-primitive field types of a .msg text, sorted, spelled 'pkg/Type'.

    A bare type inside `package` ('Pose' in geometry_msgs) becomes 'package/Pose'.
    """
    dependencies = set()
    for line in msg_text.splitlines():
        declaration = line.split("#", 1)[0].split()
        if len(declaration) < 2 or "=" in declaration[0]:
            continue
        field_type = re.split(r"[\[<]", declaration[0], maxsplit=1)[0]
        if field_type in PRIMITIVE_TYPES:
            continue
        dependencies.add(field_type if "/" in field_type else f"{package}/{field_type}")
    return sorted(dependencies)


def full_definition(type_name: str) -> str:
    """The complete ros2msg schema text for `type_name` ('pkg/msg/Type')."""
    seen: set[str] = set()

    def append_recursive(name: str) -> str:
        package, _ = split_type_name(name)
        with open(find_msg_file(name), encoding="utf-8") as msg_file:
            text = msg_file.read()
        for dependency in field_dependencies(text, package):
            if dependency not in seen:
                seen.add(dependency)
                text += f"\n{DELIMITER}\nMSG: {dependency}\n" + append_recursive(dependency)
        return text

    return append_recursive(type_name)
