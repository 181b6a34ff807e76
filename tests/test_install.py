"""A non-editable install works outside the source tree: the core packages and their data files come from the
installed wheel. Offline: the fresh venv borrows the project venv's third-party packages through a .pth file
and is built without isolation (setuptools and wheel pinned in requirements.txt)."""
import os
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("config", "planner", "hv_driver", "sim_fallback", "sequencing", "recording", "estimation", "netlab")


def run(command, cwd, timeout=300):
    env = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH", "PYTHONHOME")}
    result = subprocess.run([str(c) for c in command], cwd=cwd, env=env, capture_output=True, text=True,
                            timeout=timeout)
    assert result.returncode == 0, f"{command}\n{result.stdout[-2000:]}\n{result.stderr[-3000:]}"
    return result.stdout


def test_pip_install_then_planner_commands_run_from_the_installed_copy(tmp_path):
    source = tmp_path / "source"  # a copy, so the build writes nothing into the work tree
    source.mkdir()
    shutil.copy(ROOT / "pyproject.toml", source)
    for name in PACKAGES:
        shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
    venv = tmp_path / "venv"
    run([sys.executable, "-m", "venv", "--without-pip", venv], tmp_path)
    python = venv / "bin" / "python"
    purelib = Path(run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp_path).strip())
    (purelib / "borrowed.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    run([python, "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index", "--quiet", source],
        tmp_path)
    work = tmp_path / "elsewhere"
    work.mkdir()
    located = run([python, "-c", "import planner, softblock_config, sequencing, recording, hv_driver, sim_fallback,"
                   " estimation, netlab; print(planner.__file__); print(softblock_config.config_file())"], work).split()
    assert all(Path(path).is_relative_to(purelib) for path in located), located
    gripper = Path(located[1]) / "assemblies" / "gripper.yaml"
    shape = run([python, "-m", "planner", "fk", gripper, "--voltage", "front=2400"], work)
    assert "front_left" in shape
    out = work / "table.csv"
    assert "wrote" in run([python, "-m", "planner", "table", "--out", out], work)
    assert out.read_text().splitlines()[0] == (ROOT / "config" / "block_table.csv").read_text().splitlines()[0]
    arc = Path(located[1]) / "assemblies" / "figure2_arc.yaml"
    assert "wrote" in run([python, "-m", "estimation", "render", "--assembly", arc, "--pixel-size", "1e-3",
                           "--out", work / "arc.png"], work)
