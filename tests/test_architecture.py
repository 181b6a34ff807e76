"""The layering of pyproject.toml's import-linter contracts holds, and its list of ROS packages is complete."""
import pkgutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

pytestmark = pytest.mark.fast

ROOT = Path(__file__).resolve().parents[1]
CONTRACTS = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]


def test_import_contracts_are_kept():
    lint = subprocess.run([Path(sys.executable).with_name("lint-imports"), "--no-cache"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert lint.returncode == 0, lint.stdout[-3000:] + lint.stderr[-2000:]
    assert f"Contracts: {len(CONTRACTS)} kept, 0 broken." in lint.stdout


def _is_interface_package(module: pkgutil.ModuleInfo) -> bool:
    """A package with a generated msg, srv or action subpackage (looked at on disk, nothing imported)."""
    folder = Path(getattr(module.module_finder, "path", "")) / module.name
    return module.ispkg and any((folder / kind / "__init__.py").is_file() for kind in ("msg", "srv", "action"))


def test_the_core_contract_forbids_every_ros_interface_package_of_the_environment():
    core = next(c for c in CONTRACTS if c["name"].startswith("Core packages never import ROS"))
    installed = {m.name for m in pkgutil.iter_modules() if _is_interface_package(m)}
    assert "std_msgs" in installed and "softblock_interfaces" in installed  # the scan sees the environment
    assert installed - set(core["forbidden_modules"]) == set()
    assert {"rclpy", "softblock_ros"} <= set(core["forbidden_modules"])
