"""A plain install: what the wheel ships, and what a core install (no extras) does.

The wheel is built from the working tree (``pip wheel . --no-deps``, ~1 min) and read as a zip.
A core install is imitated in a subprocess whose imports of the extras' packages fail: a
``sitecustomize`` on ``PYTHONPATH`` puts a ``sys.meta_path`` finder first that raises
ImportError for torch, stable_baselines3, yaml, matplotlib and imageio (the processes the
leaderboard spawns inherit it), rather than building a new venv.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENV = "cir_gym/JointTracking-v2"
#: the packages of the extras a core install lacks (train: torch, SB3, PyYAML; plots)
BLOCKED = ("torch", "stable_baselines3", "yaml", "matplotlib", "imageio")

SITECUSTOMIZE = f"""
import importlib.abc
import sys

BLOCKED = {BLOCKED!r}


class NotInstalled(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {{name!r}} (blocked by the test)",
                                      name=name)
        return None


sys.meta_path.insert(0, NotInstalled())
"""


# ---------------------------------------------------------------------- the wheel
@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> zipfile.ZipFile:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation",
         "-q", "-w", str(out)],
        check=True, capture_output=True, text=True, timeout=600,
    )
    (path,) = out.glob("cir_gym-*.whl")
    with zipfile.ZipFile(path) as z:
        yield z


def test_the_wheel_ships_the_tuned_gains_the_agents_and_their_hyperparameters(wheel):
    names = set(wheel.namelist())
    gains = sorted(p.name for p in (ROOT / "cir_gym/scoring/tuned_gains").glob("*.json"))
    assert gains and all(f"cir_gym/scoring/tuned_gains/{g}" in names for g in gains)
    for path in (ROOT / "agents/trained").rglob("*"):
        if path.is_file():
            assert f"cir_gym/agents/{path.relative_to(ROOT / 'agents').as_posix()}" in names
    for path in (ROOT / "agents/hyperparams").rglob("*.yml"):
        assert f"cir_gym/agents/{path.relative_to(ROOT / 'agents').as_posix()}" in names
    assert "cir_gym/baselines/__init__.py" in names and "cir_gym/agents/__init__.py" in names
    assert "cir_gym/scoring/policies.py" in names and "cir_gym/cli.py" in names
    json.loads(wheel.read(f"cir_gym/scoring/tuned_gains/{gains[0]}"))  # not a pointer file


def test_the_wheel_installs_one_top_level_package(wheel):
    """No top-level ``baselines``, ``agents`` or ``scripts`` (other projects' import names)."""
    top = {n.split("/")[0] for n in wheel.namelist()}
    assert {t for t in top if not t.endswith(".dist-info")} == {"cir_gym"}
    dist_info = next(t for t in top if t.endswith(".dist-info"))
    entry_points = wheel.read(f"{dist_info}/entry_points.txt").decode()
    assert "cir-gym = cir_gym.cli:main" in entry_points


# ---------------------------------------------------------------------- a core install
@pytest.fixture(scope="module")
def core(tmp_path_factory):
    """Run ``python -m cir_gym.cli ARGS`` as on an install without extras: (rc, out, err)."""
    site = tmp_path_factory.mktemp("core_site")
    (site / "sitecustomize.py").write_text(SITECUSTOMIZE)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(ROOT)]),
           "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}

    def run(*args: str, cwd: Path | None = None, timeout: float = 300) -> tuple[int, str, str]:
        p = subprocess.run([sys.executable, "-m", "cir_gym.cli", *args], env=env, cwd=cwd,
                           capture_output=True, text=True, timeout=timeout)
        return p.returncode, p.stdout, p.stderr

    rc, _, err = run("list")
    assert rc == 0, err
    return run


def test_the_blocker_blocks(core, tmp_path):
    site = tmp_path / "s"
    site.mkdir()
    (site / "sitecustomize.py").write_text(SITECUSTOMIZE)
    p = subprocess.run([sys.executable, "-c", "import yaml"], capture_output=True, text=True,
                       env={**os.environ, "PYTHONPATH": str(site)})
    assert p.returncode == 1 and "blocked by the test" in p.stderr


def test_a_core_install_lists_no_agent_it_cannot_run_and_names_the_extra(core):
    rc, out, err = core("list")
    assert rc == 0 and "Traceback" not in err
    policies = [line for line in out.splitlines() if line.strip().startswith("policies:")]
    assert policies and not any("agent:" in line for line in policies)
    assert "tuned:computed_torque" in out  # the tuned gains ship with the package
    assert "pip install 'cir-gym[train]'" in out


def test_an_agent_on_a_core_install_names_the_extra_before_any_work(core, tmp_path):
    rc, out, err = core("evaluate", "--env", ENV, "--policy", "agent:ppo_100hz",
                        "--plot", str(tmp_path / "x.png"))
    assert rc == 2 and "Traceback" not in err, err
    assert "pip install 'cir-gym[" in err and "rms_error" not in out


@pytest.mark.parametrize("option, path", [("--plot", "x.png"), ("--video", "x.gif")])
def test_plot_and_video_without_the_plots_extra_fail_before_the_episodes(core, tmp_path,
                                                                         option, path):
    rc, out, err = core("evaluate", "--env", ENV, "--policy", "pd_gravity", option,
                        str(tmp_path / path))
    assert rc == 2 and "Traceback" not in err, err
    assert "pip install 'cir-gym[plots]'" in err and option in err
    assert "rms_error" not in out and not (tmp_path / path).exists()  # nothing evaluated


def test_the_leaderboard_on_a_core_install_runs_without_a_traceback(core, tmp_path):
    """Controllers and tuned controllers only, no figures (a line says why), the page."""
    out_dir = tmp_path / "lb"
    rc, _, err = core("leaderboard", "--env", "VisualServoEyeToHand-v1", "--episodes", "1",
                        "--out", str(out_dir), timeout=600)
    assert rc == 0 and "Traceback" not in err, err
    assert "pip install 'cir-gym[plots]'" in err
    md = (out_dir / "leaderboard.md").read_text()
    assert "agent:" not in md and (out_dir / "index.html").is_file()
    assert not list(out_dir.glob("*.png"))
