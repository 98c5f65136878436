"""A shipped agent exported in rl-zoo3's layout (cir_gym.agents.zoo) runs in rl-zoo3: the
episode rl-zoo3's own test env plays equals the one cir_gym.agents.load plays; ``enjoy`` runs it
from the command line; ``record_video`` through the documented ``python -c`` route."""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from cir_gym.agents.zoo import enjoy_command, export_zoo, record_video_command, zoo_env_name

from cir_gym import agents
from cir_gym.cli import main
from cir_gym.evaluation import evaluate

pytest.importorskip("rl_zoo3")

ENV = "cir_gym/JointTracking-v2"
#: a from-scratch agent with observation normalisation at 100 Hz, and a residual agent on the
#: tuned computed torque; both trained on JointTracking-v1 and scored on v2 (EARLIER_VERSIONS)
SCRATCH = "ppo_100hz@JointTracking-v1"
RESIDUAL = "residual_ppo_tuned_computed_torque@JointTracking-v1"
SEED = 1000


def _zoo_episode(run: Path, env_kwargs: dict) -> float:
    """One episode's return through rl-zoo3's python API, as its enjoy script calls it
    (saved hyperparameters → create_test_env → ALGOS[algo].load → predict)."""
    from rl_zoo3 import ALGOS, create_test_env, get_saved_hyperparams

    name = zoo_env_name(ENV)
    hyperparams, stats_path = get_saved_hyperparams(str(run / name), test_mode=True)
    venv = create_test_env(ENV, n_envs=1, stats_path=stats_path, seed=SEED,
                           should_render=False, hyperparams=hyperparams, env_kwargs=env_kwargs)
    custom = {"learning_rate": 0.0, "lr_schedule": lambda _: 0.0, "clip_range": lambda _: 0.0}
    model = ALGOS["ppo"].load(str(run / f"{name}.zip"), custom_objects=custom, device="cpu")
    obs, total, done = venv.reset(), 0.0, False
    while not done:
        action, _ = model.predict(obs, deterministic=True)
        obs, reward, dones, _ = venv.step(action)
        total, done = total + float(reward[0]), bool(dones[0])
    venv.close()
    return total


@pytest.mark.parametrize("name", [SCRATCH, RESIDUAL])
def test_the_exported_agent_plays_the_episode_agents_load_plays(tmp_path: Path, name: str):
    """rl-zoo3's stack (its test env with the exported env_wrapper, VecNormalize from the
    exported statistics, PPO.load of the shipped zip) and cir_gym.agents.load give the same
    episode return on the same seed, to 1e-6 relative: the same float32 network on the same
    observations, normalised by the same formula (VecNormalize in float64, agents.load in
    float32 after clipping: rounding only)."""
    run = export_zoo(ENV, name, tmp_path)
    assert run == tmp_path / "ppo" / "cir_gym-JointTracking-v2_1"
    args = yaml.safe_load((run / zoo_env_name(ENV) / "args.yml").read_text())
    assert args["cir_gym_agent"] == name and args["env"] == ENV
    assert args["retrain"].startswith("cir-gym train --env cir_gym/JointTracking-v2 ")
    env_kwargs = {**args["env_kwargs"], "episode_duration": 0.4}
    zoo = _zoo_episode(run, env_kwargs)
    ours = evaluate(agents.load(ENV, name), ENV, 1, SEED, **env_kwargs).episodes[0]
    assert zoo == pytest.approx(ours.episode_return, rel=1e-6, abs=1e-9)
    assert np.isfinite(zoo) and zoo != 0.0


def test_export_zoo_command_and_rl_zoo3_enjoy_run_a_shipped_agent(tmp_path: Path, capsys):
    """``cir-gym export-zoo`` numbers the experiments (``--exp-id 0`` loads the latest) and
    ``python -m rl_zoo3.enjoy --gym-packages cir_gym`` plays the agent for 30 steps."""
    assert main(["export-zoo", "--env", ENV, "--agent", RESIDUAL, "--out", str(tmp_path)]) == 0
    assert main(["export-zoo", "--env", ENV, "--agent", f"agent:{SCRATCH}",
                 "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    run = tmp_path / "ppo" / "cir_gym-JointTracking-v2_2"
    assert f"wrote {run}" in printed and "rl_zoo3.enjoy" in printed
    assert main(["export-zoo", "--env", ENV, "--agent", "nope", "--out", str(tmp_path)]) == 2
    cmd = [*shlex.split(enjoy_command(run, n_timesteps=30)),
           "--env-kwargs", "episode_duration:0.1"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "cir_gym-JointTracking-v2_2" in done.stdout and "Loading running average" in done.stdout
    # 0.1 s at the agent's 100 Hz: 10-step episodes, three of them in 30 steps
    assert done.stdout.count("Episode Length 10") == 3


@pytest.mark.slow
def test_record_video_runs_through_python_c(tmp_path: Path):
    """rl_zoo3.record_video has no --gym-packages and looks the id up in Gymnasium's registry
    before making the env (so ``--env cir_gym:cir_gym/...`` is a KeyError there): the command
    of record_video_command imports cir_gym first and writes the video."""
    pytest.importorskip("moviepy")
    run = export_zoo(ENV, SCRATCH, tmp_path / "logs")
    cmd = shlex.split(record_video_command(run, tmp_path / "videos", n_timesteps=20))
    assert cmd[:2] == [sys.executable, "-c"] and "import sys, runpy, cir_gym" in cmd[2]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert list((tmp_path / "videos").glob("*.mp4"))
