"""Where a node's supervisor process listens unless told otherwise: a path fixed by who the node is (its fully
qualified name, its ROS domain, its ports), so a node started again after its death (a respawn) reaches the
supervisor that still holds its supplies, instead of starting a second one that cannot open their ports.

The socket lies in a directory of this user's own, mode 0700 (``$XDG_RUNTIME_DIR/softblock-hv``, else
``<temp dir>/softblock-hv-<uid>``), so no other user can place a socket there for the node to talk to; the node
takes over only a supervisor of its own settings (`hv_driver.RemoteSupply`).
"""
import hashlib
import json
import os
import stat
import tempfile
from collections.abc import Sequence

from .errors import HvError

KEY_CHARS = 16  # of the sha256 in hex: a socket path has at most 107 bytes


def private_directory() -> str:
    """This user's directory for supervisor sockets, created mode 0700; HvError if it is not this user's own."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    path = (os.path.join(runtime, "softblock-hv") if runtime
            else os.path.join(tempfile.gettempdir(), f"softblock-hv-{os.getuid()}"))
    try:
        os.mkdir(path, 0o700)
    except FileExistsError:
        pass
    except OSError as error:
        raise HvError(f"cannot create the supervisor socket directory {path}: {error}") from error
    info = os.lstat(path)
    if not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid() or info.st_mode & 0o077:
        raise HvError(f"{path} is not a directory of this user's own with mode 0700 (owner uid {info.st_uid}, mode "
                      f"{stat.filemode(info.st_mode)}): remove it, or give the node a supervisor_socket")
    return path


def node_socket_path(node: str, domain_id: int, ports: Sequence[str]) -> str:
    """The supervisor socket of the node named ``node`` (fully qualified) in ROS domain ``domain_id`` driving
    ``ports``: the same path every time the node starts."""
    key = hashlib.sha256(json.dumps([node, domain_id, list(ports)]).encode()).hexdigest()[:KEY_CHARS]
    return os.path.join(private_directory(), f"{key}.sock")
