"""The supervisor socket a node uses by default: the same path each time the same node (name, ROS domain, ports)
starts, in a directory of the user's own; a directory others may write to is refused, naming it."""
import os
import stat

import pytest

from hv_driver import HvError
from hv_driver.socket_path import node_socket_path

pytestmark = pytest.mark.fast


@pytest.fixture
def sockets(tmp_path, monkeypatch):
    """Where the supervisor sockets go: the user's runtime directory is the test's own."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    return tmp_path / "softblock-hv"


def test_the_same_node_gets_the_same_path_and_another_node_another(sockets):
    path = node_socket_path("/hv_driver", 7, ["/dev/ttyUSB0"])
    assert path == node_socket_path("/hv_driver", 7, ["/dev/ttyUSB0"])
    assert os.path.dirname(path) == str(sockets) and len(path.encode()) < 108
    others = {node_socket_path("/left/hv_driver", 7, ["/dev/ttyUSB0"]), node_socket_path("/hv_driver", 8,
              ["/dev/ttyUSB0"]), node_socket_path("/hv_driver", 7, ["/dev/ttyUSB1"]),
              node_socket_path("/hv_driver", 7, [])}
    assert path not in others and len(others) == 4
    assert stat.S_IMODE(os.lstat(sockets).st_mode) == 0o700


def test_a_socket_directory_others_may_write_to_is_refused_naming_it(sockets):
    sockets.mkdir()
    os.chmod(sockets, 0o777)
    with pytest.raises(HvError, match="softblock-hv is not a directory of this user's own with mode 0700"):
        node_socket_path("/hv_driver", 7, [])


def test_a_link_in_place_of_the_directory_is_refused(sockets, tmp_path_factory):
    sockets.symlink_to(tmp_path_factory.mktemp("elsewhere"))
    with pytest.raises(HvError, match="not a directory of this user's own"):
        node_socket_path("/hv_driver", 7, [])
