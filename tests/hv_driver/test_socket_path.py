"""The supervisor socket a node uses by default: the same path each time the same node (name, ROS domain, ports)
starts, in a directory of the user's own; a directory others may write to is refused, naming it."""
import os
import stat

import pytest

from hv_driver import HvError
from hv_driver.socket_path import node_socket_path

pytestmark = pytest.mark.fast


@pytest.fixture
def runtime(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    return tmp_path


def test_the_same_node_gets_the_same_path_and_another_node_another(runtime):
    path = node_socket_path("/hv_driver", 7, ["/dev/ttyUSB0"])
    assert path == node_socket_path("/hv_driver", 7, ["/dev/ttyUSB0"])
    assert os.path.dirname(path) == str(runtime / "softblock-hv") and len(path.encode()) < 108
    others = {node_socket_path("/left/hv_driver", 7, ["/dev/ttyUSB0"]), node_socket_path("/hv_driver", 8,
              ["/dev/ttyUSB0"]), node_socket_path("/hv_driver", 7, ["/dev/ttyUSB1"]),
              node_socket_path("/hv_driver", 7, [])}
    assert path not in others and len(others) == 4
    assert stat.S_IMODE(os.lstat(runtime / "softblock-hv").st_mode) == 0o700


def test_a_socket_directory_others_may_write_to_is_refused_naming_it(runtime):
    (runtime / "softblock-hv").mkdir(mode=0o777)
    os.chmod(runtime / "softblock-hv", 0o777)
    with pytest.raises(HvError, match="softblock-hv is not a directory of this user's own with mode 0700"):
        node_socket_path("/hv_driver", 7, [])


def test_a_link_in_place_of_the_directory_is_refused(runtime, tmp_path_factory):
    (runtime / "softblock-hv").symlink_to(tmp_path_factory.mktemp("elsewhere"))
    with pytest.raises(HvError, match="not a directory of this user's own"):
        node_socket_path("/hv_driver", 7, [])
