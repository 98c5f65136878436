"""Residual RL on the native batched env (agents.batched.BatchedResidualAction) against the single
env under agents.residual.ResidualAction, and ``cir-gym train --residual`` with ``vec_env:
batched``.

Tolerance: each batched copy is the single agent-ready variant to 1e-12 (its own tests,
tests/test_vector_agent_ready.py), and the course controllers give a row in a batch the action
they give it alone (tests/test_batched_laws.py), so the residual copies are the single ones to
that round-off. What the agent sees is float32 (the flat observation, SB3's rewards): those are
compared to 1e-6 relative (≈ 8 float32 ulps); the float64 episode metrics to 1e-9; ends,
lengths and success exactly. (Measured: bit for bit.)
"""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import yaml

pytest.importorskip("stable_baselines3")

from cir_gym.agents.batched import make_batched_vec_env
from cir_gym.agents.observation import ObservationLayout
from cir_gym.agents.train import EnvFactory
from lockstep import SB3_METRIC_RTOL as METRIC_RTOL
from lockstep import SB3_RTOL as RTOL
from lockstep import sb3_step

from cir_gym import agents, baselines
from cir_gym.envs import BATCHED_ENVIRONMENTS
from cir_gym.evaluation import evaluate

SCALE = 0.5


def agent_ready(name: str) -> str:
    """The registered batched id of the agent-ready variant ``name`` (its version is not fixed
    here: the ids are renamed as the variants change)."""
    ids = [k for k in BATCHED_ENVIRONMENTS if k.split("/")[-1].rsplit("-v", 1)[0] == name]
    assert len(ids) == 1, (name, ids)
    return ids[0]


PEG = agent_ready("PegInHoleImpedance")
CONTACT = agent_ready("AdmittanceContactImpedance")


def layout_of(env_id: str, kwargs: dict) -> ObservationLayout:
    probe = gym.make(env_id, **kwargs)
    layout = ObservationLayout.from_space(probe.observation_space)
    probe.close()
    return layout


# (id, base controller, env arguments, steps, copy 0 pushes down): on the peg, copy 0's residual
# pushes the setpoint down and the 15-N force limit ends its episodes every few steps, while
# copies 1 and 2 reach the face and start the spiral search (the law's state: phase, angle,
# centre) before their 40-step episodes end: a search state carried into the next episode
# changes its actions. On the contact task the law's state holds the path's time.
LOCKSTEP_CASES = [
    (PEG, "impedance_spiral", {"episode_duration": 2.0, "start_height": 0.002,
                               "force_limit": 15.0}, 85, True),
    (CONTACT, "impedance_setpoint", {"episode_duration": 1.0, "randomize": True}, 45, False),
]


@pytest.mark.parametrize("env_id, controller, kwargs, steps, push", LOCKSTEP_CASES,
                         ids=["peg", "contact"])
def test_each_copy_is_the_single_env_under_residual_action(env_id, controller, kwargs, steps,
                                                           push):
    """Three copies of the batched residual training env (agents.train's stack: flat
    observation, Monitor statistics) and three single envs under ResidualAction, same seeds
    and random agent actions, through several episode ends: the ended copies' controller state
    restarts with their next episode while the others run on."""
    layout = layout_of(env_id, kwargs)
    n, seed = 3, 11
    venv = make_batched_vec_env(env_id, kwargs, layout, n, seed, residual=controller,
                                scale=SCALE)
    singles = [EnvFactory(env_id, kwargs, layout, controller, SCALE)() for _ in range(n)]
    obs = venv.reset()
    for i, env in enumerate(singles):
        np.testing.assert_allclose(obs[i], env.reset(seed=seed + i)[0], rtol=RTOL, atol=RTOL)
    rng = np.random.default_rng(0)
    m = venv.action_space.shape[0]
    ends = []
    for k in range(steps):
        a = rng.uniform(-0.2, 0.2, (n, m)).astype(np.float32)
        if push:
            a[0, 2] = -1.0
        ends += [(k, i) for i, _ in sb3_step(venv, singles, a, k,
                                             ("controller_action", "residual_action"))]
    venv.close()
    assert len({i for _, i in ends}) == n  # every copy was autoreset
    if push:  # ends at different steps: copies restart while the others go on
        assert len({k for k, _ in ends}) > 3


@pytest.mark.parametrize("env_id, controller, kwargs", [
    (PEG, "impedance_spiral", {"episode_duration": 3.0, "start_height": 0.002}),
    (CONTACT, "impedance_setpoint", {"episode_duration": 2.0}),
], ids=["peg", "contact"])
def test_a_zero_residual_is_the_controller_alone(env_id, controller, kwargs):
    """a_agent = 0 on the batched residual env: every copy's first episode has the controller's
    own length, success, metrics and return (``evaluate`` on the same seeds; on the peg the
    spiral search runs from 1.5 s on, in contact on the block's face)."""
    n, seed = 3, 1000
    layout = layout_of(env_id, kwargs)
    venv = make_batched_vec_env(env_id, kwargs, layout, n, seed, residual=controller,
                                scale=SCALE)
    venv.reset()
    first: list[dict | None] = [None] * n
    zero = np.zeros((n, venv.action_space.shape[0]), dtype=np.float32)
    while any(f is None for f in first):
        _, _, dones, infos = venv.step(zero)
        for i in np.flatnonzero(dones):
            if first[i] is None:
                first[i] = infos[i]
    venv.close()
    alone = evaluate(baselines.make(controller, env_id, env_kwargs=kwargs), env_id, n,
                     seed=seed, **kwargs)
    for info, episode in zip(first, alone.episodes, strict=True):
        assert info["episode"]["l"] == episode.length
        assert info["is_success"] == episode.success
        # the return sums SB3's float32 rewards
        assert info["episode"]["r"] == pytest.approx(episode.episode_return, rel=RTOL)
        for name, value in episode.metrics.items():
            assert info["episode_metrics"][name] == pytest.approx(value, rel=METRIC_RTOL,
                                                                  abs=1e-12), name


def test_batched_residual_arguments_are_checked():
    kwargs = {"episode_duration": 1.0}
    layout = layout_of(PEG, kwargs)
    with pytest.raises(ValueError, match="does not apply"):
        make_batched_vec_env(PEG, kwargs, layout, 2, 0, residual="impedance_setpoint",
                             scale=SCALE)
    with pytest.raises(ValueError, match="scale"):
        make_batched_vec_env(PEG, kwargs, layout, 2, 0, residual="impedance_spiral", scale=3.0)
    with pytest.raises(ValueError, match="need residual"):
        make_batched_vec_env(PEG, kwargs, layout, 2, 0, scale=SCALE)
    venv = make_batched_vec_env(PEG, kwargs, layout, 2, 0, residual="impedance_spiral",
                                scale=SCALE)
    venv.reset()
    with pytest.raises(ValueError, match="NaN"):
        venv.step(np.full((2, venv.action_space.shape[0]), np.nan, dtype=np.float32))
    venv.close()


def residual_hyperparams(tmp_path: Path, **overrides) -> Path:
    """agents/hyperparams/contact/ppo.yml with ``vec_env: batched`` (and ``overrides``) in its
    residual section."""
    source = agents.TRAINED_DIR.parent / "hyperparams" / "contact" / "ppo.yml"
    data = yaml.safe_load(source.read_text())
    data["residual"]["default"].update(vec_env="batched", **overrides)
    path = tmp_path / "ppo.yml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_train_runs_a_residual_on_the_batched_env(tmp_path, monkeypatch):
    """``train(..., residual=...)`` with ``vec_env: batched`` steps its copies on the batched
    residual env (the controller and scale of config.yml); early_termination is still refused
    there."""
    import cir_gym.agents.train as train_module
    from cir_gym.agents.hyperparameters import HyperparameterError

    made = []

    def counted(*args, **kwargs):
        venv = make_batched_vec_env(*args, **kwargs)
        made.append(venv.venv)
        return venv

    monkeypatch.setattr(train_module, "make_batched_vec_env", counted)
    hp = residual_hyperparams(tmp_path, n_envs=2, n_steps=64, batch_size=64)
    kw = {"episode_duration": 1.0}
    run = train_module.train(PEG, "ppo", timesteps=128, residual="impedance_spiral",
                             out=tmp_path, env_kwargs=kw, hyperparams_path=hp,
                             progress_bar=False, verbose=0)
    (residual,) = made
    assert residual.controller.name == "impedance_spiral" and residual.num_envs == 2
    np.testing.assert_array_equal(residual.scale, SCALE)
    assert json.loads((run / "meta.json").read_text())["timesteps"] == 128
    hp = residual_hyperparams(tmp_path, early_termination={"max_error": 1.0})
    with pytest.raises(HyperparameterError, match="early_termination"):
        train_module.train(PEG, "ppo", timesteps=128, residual="impedance_spiral",
                           out=tmp_path, name="e", env_kwargs=kw, hyperparams_path=hp,
                           progress_bar=False, verbose=0)


@pytest.mark.slow
def test_cli_trains_a_residual_on_the_batched_env(tmp_path):
    """``cir-gym train --env <PegInHoleImpedance> --residual impedance_spiral`` with the
    contact PPO recipe and ``vec_env: batched``: 4096 steps on 16 batched copies; config.yml
    records the residual; the agent loads with its controller and evaluates batched as
    sequentially."""
    from cir_gym.cli import main

    hp = residual_hyperparams(tmp_path)
    code = main(["train", "--env", PEG, "--algo", "ppo", "--residual", "impedance_spiral",
                 "--hyperparams", str(hp), "--timesteps", "4096", "--out", str(tmp_path),
                 "--name", "r", "--set", "episode_duration=2.0"])
    assert code == 0
    run = tmp_path / PEG.split("/")[-1] / "r"
    config = yaml.safe_load((run / "config.yml").read_text())
    m = gym.make(PEG).action_space.shape[0]
    assert config["residual"] == {"controller": "impedance_spiral", "scale": [SCALE] * m}
    assert config["hyperparams"]["vec_env"] == "batched"
    meta = json.loads((run / "meta.json").read_text())
    assert meta["finished"] and meta["timesteps"] == 4096 and meta["n_envs"] == 16
    agent = agents.load(PEG, "r", path=run)
    assert agent.controller is not None and agent.controller.name == "impedance_spiral"
    kw = {"episode_duration": 2.0}
    batched = evaluate(agent, PEG, 2, seed=100_000, batched=True, **kw)
    sequential = evaluate(agent, PEG, 2, seed=100_000, batched=False, **kw)
    for b, s in zip(batched.episodes, sequential.episodes, strict=True):
        assert (b.length, b.success) == (s.length, s.success)
        assert b.episode_return == pytest.approx(s.episode_return, rel=1e-4)
