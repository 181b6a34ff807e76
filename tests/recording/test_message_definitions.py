"""Schema text as rosbag2 writes it: root .msg verbatim, then each nested type once, sorted."""
import os
import re

import pytest
from ament_index_python.packages import get_package_share_directory

from recording.message_definitions import (DELIMITER, DefinitionNotFoundError,
                                                         field_dependencies, full_definition)

pytestmark = pytest.mark.fast


def msg_text(package: str, name: str) -> str:
    path = os.path.join(get_package_share_directory(package), "msg", name + ".msg")
    with open(path, encoding="utf-8") as msg_file:
        return msg_file.read()


def sections(text: str) -> list[str]:
    return re.findall(rf"^{DELIMITER}\nMSG: (\S+)$", text, re.MULTILINE)


def test_hv_state_definition_has_every_nested_type_in_rosbag2_order():
    text = full_definition("softblock_interfaces/msg/HvState")
    assert text.startswith(msg_text("softblock_interfaces", "HvState"))
    assert sections(text) == ["softblock_interfaces/HvChannelState", "std_msgs/Header",
                              "builtin_interfaces/Time"]
    header_part = text.split("MSG: std_msgs/Header\n", 1)[1]
    assert header_part.startswith(msg_text("std_msgs", "Header"))


def test_assembly_definition_lists_shared_dependencies_once():
    names = sections(full_definition("softblock_interfaces/msg/Assembly"))
    assert len(names) == len(set(names))
    # bare names inside geometry_msgs (Point in Pose) are spelled with their package
    assert {"geometry_msgs/Pose", "geometry_msgs/Point", "geometry_msgs/Quaternion",
            "softblock_interfaces/BlockDesign", "builtin_interfaces/Time"} <= set(names)


def test_field_dependencies_skip_primitives_constants_and_comments():
    text = ("# Pose pose is only a comment\nuint32 FAULT=1\nstring<=8 name\nfloat64[3] xyz\n"
            "Point[] points  # bare\nstd_msgs/Header header\n")
    assert field_dependencies(text, "geometry_msgs") == ["geometry_msgs/Point", "std_msgs/Header"]


def test_unknown_package_and_malformed_name_are_named_in_the_error():
    with pytest.raises(DefinitionNotFoundError, match="no_such_msgs"):
        full_definition("no_such_msgs/msg/Thing")
    with pytest.raises(DefinitionNotFoundError, match="std_msgs/msg/NoSuchType"):
        full_definition("std_msgs/msg/NoSuchType")
    with pytest.raises(ValueError, match="type_name"):
        full_definition("not a type")
