"""The ROS package's conventions: `ros2 run` finds every command the docs name (console scripts installed into
lib/softblock_ros), and package.xml declares what the nodes need at run time (every ROS package they import, and
the rosdep keys of the Python libraries they and the core import). The pip install of the core brings every
library the core imports, and its `nodes` extra what the nodes import beyond it, within the versions pinned in
constraints.txt (the README's apt install path)."""
import ast
import configparser
import importlib
import importlib.metadata
import os
import re
import sys
import tomllib
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

pytestmark = pytest.mark.fast

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "ros_ws" / "src" / "softblock_ros"
CORE = ("planner", "hv_driver", "sim_fallback", "sequencing", "recording", "estimation", "config")
# Python libraries by rosdep key; the others come only with `pip install` of the core (see package.xml).
ROSDEP_KEYS = {"numpy": "python3-numpy", "scipy": "python3-scipy", "yaml": "python3-yaml", "serial": "python3-serial",
               "matplotlib": "python3-matplotlib", "PIL": "python3-pil"}
PIP_ONLY = {"mcap", "mcap_ros2", "numba", "contourpy", "foxglove", "zstandard", "lz4"}  # contourpy comes with matplotlib; zstandard, lz4 with mcap
APT_ONLY = {"launch", "launch_ros"}  # ROS packages without PyPI wheels: `ros2 launch` needs the apt install
NODE_SOURCES = (PACKAGE / "softblock_ros", PACKAGE / "launch")  # setup.py runs at build time only
OWN = {"softblock_ros", "softblock_config", *CORE}
COMMANDS = ("hv_console", "run_sequence", "demo", "launcher", "hv_driver", "sequencer", "recorder", "player",
            "analyze_recording")


def console_scripts() -> dict[str, str]:
    tree = ast.parse((PACKAGE / "setup.py").read_text())
    call = next(node for node in ast.walk(tree) if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "setup")
    entry_points = ast.literal_eval(next(k.value for k in call.keywords if k.arg == "entry_points"))
    return dict(line.replace(" ", "").split("=") for line in entry_points["console_scripts"])


def imported_modules(*folders: Path) -> set[str]:
    names = set()
    for folder in folders:
        for path in folder.rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Import):
                    names |= {alias.name.split(".")[0] for alias in node.names}
                elif isinstance(node, ast.ImportFrom) and node.level == 0:
                    names.add(node.module.split(".")[0])
    return names - set(sys.stdlib_module_names) - {"__future__"}


def exec_depends() -> set[str]:
    return {element.text for element in ElementTree.parse(PACKAGE / "package.xml").getroot().iter("exec_depend")}


def is_ros_package(name: str) -> bool:
    return name in APT_ONLY or any((Path(prefix) / "share" / name / "package.xml").is_file()
               for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if prefix)


@pytest.mark.parametrize("command", COMMANDS)
def test_each_command_the_docs_run_is_a_console_script_whose_target_exists(command):
    scripts = console_scripts()
    assert command in scripts, f"setup.py has no console script {command!r}: `ros2 run softblock_ros {command}` fails"
    module, function = scripts[command].split(":")
    assert callable(getattr(importlib.import_module(module), function))


def test_console_scripts_install_where_ros2_run_looks():
    config = configparser.ConfigParser()
    config.read(PACKAGE / "setup.cfg")
    assert config["develop"]["script_dir"] == config["install"]["install_scripts"] == "$base/lib/softblock_ros"


def test_every_console_script_is_in_the_built_workspace():
    lib = ROOT / "ros_ws" / "install" / "softblock_ros" / "lib" / "softblock_ros"
    missing = sorted(name for name in console_scripts() if not (lib / name).is_file())
    assert not missing, f"{missing} not in {lib}: rerun scripts/setup_env.sh"


def test_every_ros_package_the_nodes_import_is_an_exec_depend():
    ros_imports = {name for name in imported_modules(*NODE_SOURCES) - OWN if is_ros_package(name)}
    assert {"rclpy", "launch", "launch_ros", "ament_index_python"} <= ros_imports
    assert not ros_imports - exec_depends(), f"imported but not declared in package.xml: {ros_imports - exec_depends()}"


def test_every_library_the_nodes_and_the_core_import_is_declared_or_named_as_pip_only():
    libraries = {name for name in imported_modules(*NODE_SOURCES, *(ROOT / c for c in CORE)) - OWN
                 if not is_ros_package(name)}
    assert not libraries - set(ROSDEP_KEYS) - PIP_ONLY, f"no rosdep key listed for {libraries - set(ROSDEP_KEYS) - PIP_ONLY}"
    missing = {ROSDEP_KEYS[name] for name in libraries & set(ROSDEP_KEYS)} - exec_depends()
    assert not missing, f"package.xml lacks {missing}"


def pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def installed_folders() -> list[Path]:
    """The folders of the packages pyproject.toml installs (config/ as softblock_config)."""
    settings = pyproject()["tool"]["setuptools"]
    tops = {name.split(".")[0] for name in settings["packages"]}
    return sorted(ROOT / settings["package-dir"].get(name, name) for name in tops)


def requirements(*extras: str) -> dict[str, Requirement]:
    project = pyproject()["project"]
    optional = project.get("optional-dependencies", {})
    listed = [*project["dependencies"], *(r for extra in extras for r in optional.get(extra, []))]
    return {canonicalize_name(requirement.name): requirement for requirement in map(Requirement, listed)}


def distributions(modules: set[str]) -> dict[str, str]:
    """Distribution (canonical name) -> the imported module it provides, for third-party modules."""
    provided = importlib.metadata.packages_distributions()
    return {canonicalize_name(dist): module for module in modules for dist in provided.get(module, [])}


def third_party_imports(*folders: Path) -> set[str]:
    return {name for name in imported_modules(*folders) - OWN if not is_ros_package(name)}


def test_the_pip_install_of_the_core_brings_every_library_the_core_imports():
    imported = distributions(third_party_imports(*installed_folders()))
    missing = {dist: module for dist, module in imported.items() if dist not in requirements()}
    assert not missing, f"imported by the core but not in pyproject.toml's dependencies: {missing}"


def test_the_nodes_extra_brings_every_library_the_nodes_import():
    imported = distributions(third_party_imports(*NODE_SOURCES))
    missing = {dist: module for dist, module in imported.items() if dist not in requirements("nodes")}
    assert not missing, f"imported by the nodes but in neither the dependencies nor the nodes extra: {missing}"


def test_every_requirement_of_pyproject_admits_the_version_the_suite_runs():
    pinned = {canonicalize_name(name): version for line in (ROOT / "constraints.txt").read_text().splitlines()
              if "==" in line and not line.startswith("#") for name, version in [line.split("#")[0].strip().split("==")]}
    for name, requirement in requirements(*pyproject()["project"].get("optional-dependencies", {})).items():
        assert name in pinned, f"pyproject.toml requires {name}, which constraints.txt does not pin"
        assert requirement.specifier.contains(pinned[name]), (
            f"pyproject.toml requires {requirement}, constraints.txt pins {name}=={pinned[name]}")


def test_the_ros_package_installs_every_data_file_of_the_core_config():
    """share/softblock_ros/config holds what softblock_config holds (it lacked the sequences and the layout)."""
    config = ROOT / "config"
    patterns = pyproject()["tool"]["setuptools"]["package-data"]["softblock_config"]
    core = {str(path.relative_to(config)) for pattern in patterns for path in config.glob(pattern) if path.is_file()}
    share = ROOT / "ros_ws" / "install" / "softblock_ros" / "share" / "softblock_ros" / "config"
    installed = {str(path.relative_to(share)) for path in share.rglob("*") if path.is_file()}
    assert core <= installed, f"not in {share} (rerun scripts/setup_env.sh): {sorted(core - installed)}"
    assert installed <= core, f"in {share} but not in the core's package data: {sorted(installed - core)}"


def test_the_readme_names_every_command_ros2_run_offers():
    text = (ROOT / "README.md").read_text()
    listed = re.search(r"`ros2 run softblock_ros <node>` works for (.*?)\.(?:\s|$)", text, re.S)
    assert listed, "README.md: the sentence listing what `ros2 run softblock_ros <node>` offers is gone"
    missing = sorted(set(console_scripts()) - set(re.findall(r"`(\w+)`", listed.group(1))))
    assert not missing, f"README.md's `ros2 run` list lacks {missing}"
