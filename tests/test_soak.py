"""The soak benchmark (benchmarks/soak.py) as a test: random steps, no warnings of any kind."""

from __future__ import annotations

import importlib.util
import warnings
from pathlib import Path
from types import ModuleType, SimpleNamespace
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import cir_gym

SOAK = Path(__file__).parents[1] / "benchmarks" / "soak.py"


def _soak_module() -> ModuleType:
    spec = importlib.util.spec_from_file_location("cir_gym_soak", SOAK)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_soak_main_rejects_bad_arguments_with_status_2() -> None:
    """main(argv) returns an exit status instead of exiting the calling process."""
    soak = _soak_module()
    assert soak.main(["--steps", "5"]) == 2
    assert soak.main(["--steps", "100", "--env", "cir_gym/NoSuchEnv-v0"]) == 2


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(cir_gym.ENVIRONMENTS))
def test_soak_5000_steps_without_warnings(env_id: str, capsys: pytest.CaptureFixture) -> None:
    """5000 random steps with resets: exit status 0, no Python and no MuJoCo warnings (the
    memory target is for long runs: 5000 steps only check that nothing leaks grossly)."""
    soak = _soak_module()
    status = soak.main(["--steps", "5000", "--env", env_id, "--reset-every", "300",
                        "--max-growth-mb", "50"])
    out = capsys.readouterr().out
    assert status == 0, out
    assert "| Python warnings | 0 | 0 ok |" in out, out
    assert "| MuJoCo warnings (messages; counters) | 0; none | 0 ok |" in out, out


class _Faulty(gym.Wrapper):
    """Every 50th step: a NaN in the simulator state (MuJoCo warns) and a Python warning."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.k = 0

    def step(self, action: Any) -> Any:
        self.k += 1
        if self.k % 50 == 0:
            self.env.unwrapped.data.qvel[0] = np.nan
            warnings.warn("planted by the test", UserWarning, stacklevel=1)
        return self.env.step(action)


def test_soak_counts_python_and_mujoco_warnings(monkeypatch: pytest.MonkeyPatch,
                                                capsys: pytest.CaptureFixture) -> None:
    """Planted faults show up in both counts and make main() return 1."""
    soak = _soak_module()
    monkeypatch.setattr(soak, "gym", SimpleNamespace(make=lambda e: _Faulty(gym.make(e))))
    result = soak.soak("cir_gym/JointTracking-v2", 200, 1000, 0)
    assert result["warnings"] == 4 and result["diverged"] == 4, result
    assert result["mujoco_messages"] == 4, result
    assert all("Nan" in m for m in result["first_mujoco_messages"]), result
    assert soak.main(["--steps", "200", "--env", "cir_gym/JointTracking-v2"]) == 1
    assert "MuJoCo warning: " in capsys.readouterr().out
