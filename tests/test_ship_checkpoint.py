"""agents.train.ship(which="checkpoint"): a run's saved checkpoint ships as an agent with its
own observation statistics, loads without unpickling and acts as the checkpoint does, and its
record says which checkpoint was shipped, how it was chosen, and still retrains the whole run."""

from __future__ import annotations

import json
import pickle
import shlex
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

pytest.importorskip("stable_baselines3")

from test_agents import ENV, SHORT, tiny_hyperparams
from test_provenance import check_filed, check_finished

from cir_gym import agents
from cir_gym.evaluation import evaluate

SELECTION = {"command": "python scripts/research/eval_vs_agents.py select --env " + ENV,
             "rule": "highest success rate, then lowest final-error IQM, then fewest steps",
             "seeds": [8000, 8029]}


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A seed run of 256 steps on 50-step episodes: checkpoints at 128 and 256 steps."""
    from cir_gym.agents.train import train

    tmp = tmp_path_factory.mktemp("runs")
    return train(ENV, "ppo", out=tmp, env_kwargs=SHORT, hyperparams_path=tiny_hyperparams(tmp),
                 name="ppo/seed_3", seed=3, progress_bar=False, verbose=0)


def test_a_checkpoint_ships_with_its_own_statistics_and_acts_as_it_does(run, tmp_path):
    from cir_gym.agents.train import ship
    from stable_baselines3 import PPO

    trained = tmp_path / "trained"
    target = ship(run, which="checkpoint", steps=128, selection=SELECTION,
                  dest=trained / "JointTracking-v2" / "ppo" / "seed_3")
    ckpt = run / "checkpoints"
    assert (target / "model.zip").read_bytes() == (ckpt / "model_128_steps.zip").read_bytes()
    stats_file = ckpt / "model_vecnormalize_128_steps.pkl"
    assert (target / "vecnormalize.pkl").read_bytes() == stats_file.read_bytes()
    with stats_file.open("rb") as f:
        stats = pickle.load(f)
    with np.load(target / "normalization.npz", allow_pickle=False) as z:
        np.testing.assert_array_equal(z["obs_mean"], stats.obs_rms.mean)
        np.testing.assert_array_equal(z["obs_var"], stats.obs_rms.var)
        assert bool(z["norm_obs"]) and float(z["clip_obs"]) == stats.clip_obs
    with np.load(run / "normalization.npz", allow_pickle=False) as final:
        assert not np.allclose(final["obs_mean"], stats.obs_rms.mean)  # not the final's

    agent = agents.load(ENV, "ppo", path=target)
    reference = PPO.load(str(ckpt / "model_128_steps.zip"), device="cpu")
    env = gym.make(ENV, **SHORT)
    obs, _ = env.reset(seed=4)
    for _ in range(5):
        action, _ = agent.predict(obs, deterministic=True)
        expected, _ = reference.predict(stats.normalize_obs(agent.flatten(obs)),
                                        deterministic=True)
        np.testing.assert_allclose(action, expected, atol=1e-6)
        assert env.action_space.contains(action)
        obs, *_ = env.step(action)
    env.close()
    result = evaluate(agent, ENV, 1, seed=100_000, **SHORT)
    assert np.isfinite(result.summary["rms_error"]["mean"])

    config = yaml.safe_load((target / "config.yml").read_text())
    run_config = yaml.safe_load((run / "config.yml").read_text())
    meta = json.loads((target / "meta.json").read_text())
    assert config["selection"] == {**SELECTION, "model": "checkpoint", "steps": 128}
    assert config["retrain"] == run_config["retrain"]  # trains the whole run, not 128 steps
    argv = shlex.split(config["retrain"])
    assert int(argv[argv.index("--timesteps") + 1]) == run_config["n_timesteps"] == 256
    assert meta["shipped_model"] == "checkpoint" and meta["shipped_steps"] == 128
    assert meta["timesteps"] == 256 and meta["finished"]
    check_filed(target, trained)
    check_finished(target)


@pytest.mark.parametrize("kwargs, match", [
    ({"which": "checkpoint", "selection": SELECTION}, "steps=<N>"),
    ({"which": "checkpoint", "steps": 100, "selection": SELECTION}, r"saved: \[128, 256\]"),
    ({"which": "checkpoint", "steps": 128}, "selection="),
    ({"which": "checkpoint", "steps": 128, "selection": {"rule": "best"}}, "selection="),
    ({"which": "final", "steps": 128}, "which='checkpoint' only"),
    ({"which": "latest"}, "which must be one of"),
])
def test_ship_refuses_a_checkpoint_it_cannot_name_or_explain(run, tmp_path, kwargs, match):
    from cir_gym.agents.train import ship

    with pytest.raises(ValueError, match=match):
        ship(run, dest=tmp_path / "t", **kwargs)
    assert not (tmp_path / "t").exists()


def test_every_seed_shipped_at_a_checkpoint_records_why():
    """A shipped seed at a checkpoint records the rule and the command that chose it (a
    script of the repository) and the checkpoint's steps, within the run that meta.json
    describes and its retrain line trains. At least one seed ships at a checkpoint (the five
    VisualServoEyeToHand-v1 ppo seeds), so the checks below run."""
    root = Path(__file__).resolve().parents[1]
    shipped = [d for d in sorted(agents.TRAINED_DIR.rglob("meta.json"))
               if json.loads(d.read_text()).get("shipped_model") == "checkpoint"]
    assert shipped, f"no seed under {agents.TRAINED_DIR} is shipped at a checkpoint"
    for meta_file in shipped:
        meta = json.loads(meta_file.read_text())
        config = yaml.safe_load((meta_file.parent / "config.yml").read_text())
        selection = config.get("selection") or {}
        assert {"command", "rule"} <= set(selection), meta_file.parent
        assert selection["model"] == "checkpoint"
        assert selection["steps"] == meta["shipped_steps"] <= meta["timesteps"], meta_file.parent
        script = shlex.split(selection["command"])[1]
        assert (root / script).is_file(), selection["command"]
