"""position_spiral: hybrid_spiral before its force loop (baselines/hybrid.py at 36b763b^), kept
under an honest name: position control with a spiral search, the F/T reading used only to
detect the contact. Its batched form is checked with the other PegInHole laws in
tests/test_batched_laws.py."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from cir_gym.baselines.base import InvalidGain
from cir_gym.baselines.hybrid import (
    APPROACH,
    FOUND,
    SEARCH,
    HybridSpiralGains,
    PositionSpiralGains,
    _fields,
)

from cir_gym import baselines

ENV = "cir_gym/PegInHole-v2"
#: written by tests/data/make_pre_loop_spiral.py: 800 steps of PegInHole-v2 (seed 1058, start
#: 2 mm above the face) driven by the pre-loop hybrid_spiral: its observations and float32
#: actions, and its phase per step (first contact at step 365, the drop at 623)
FIXTURE = Path(__file__).parent / "data" / "pre_loop_spiral.npz"
OBS_KEYS = ("q", "qd", "peg_pos", "peg_quat", "peg_twist", "wrench", "hole_pos", "hole_quat")
#: the tolerance on an action (its scale is 1): float32 rounding of the same float64 law
ATOL = 1e-6


@pytest.fixture(scope="module")
def recorded() -> dict[str, np.ndarray]:
    with np.load(FIXTURE) as data:
        return {key: data[key] for key in data.files}


def _observation(recorded: dict[str, np.ndarray], k: int) -> dict[str, np.ndarray]:
    """Step ``k``'s observation (the nominal hole pose is stored once)."""
    return {key: recorded[key] if key.startswith("hole") else recorded[key][k]
            for key in OBS_KEYS}


def _play(name: str, recorded: dict[str, np.ndarray], **gains: float):
    """``name`` fed the recorded observations from the episode's start (its own state):
    actions (T, 7) and the policy's phase after each step (T,)."""
    policy = baselines.make(name, ENV, env_kwargs={"start_height": float(recorded["start_height"])},
                            **gains)
    state, actions, modes = None, [], []
    for k in range(len(recorded["actions"])):
        action, state = policy.predict(_observation(recorded, k), state, np.array([k == 0]))
        actions.append(action)
        modes.append(float(_fields(np.asarray(state)[0], policy.layout)["mode"]))
    return np.array(actions), np.array(modes)


def test_the_actions_are_the_pre_loop_hybrid_spirals(recorded) -> None:
    """On the pre-loop law's own episode (the approach, the first contact, the spiral search,
    the drop and the insertion), position_spiral's actions equal that law's to float32
    rounding and its phases change at the same steps. hybrid_spiral with crossover_ratio=0 is
    not this law: its search adds the in-plane motion's inertial coupling to the axial push."""
    old = recorded["actions"]
    assert set(np.unique(recorded["old_mode"])) == {APPROACH, SEARCH, FOUND}
    actions, modes = _play("position_spiral", recorded)
    np.testing.assert_allclose(actions, old, rtol=0, atol=ATOL)
    np.testing.assert_array_equal(modes, recorded["old_mode"])
    no_loop, _ = _play("hybrid_spiral", recorded, crossover_ratio=0.0)
    searching = recorded["old_mode"] == SEARCH
    assert np.abs(no_loop - old)[searching].max() > 100 * ATOL
    np.testing.assert_allclose(no_loop[~searching], old[~searching], rtol=0, atol=ATOL)


def test_after_the_contact_the_wrench_enters_no_command(recorded) -> None:
    """From the step after the first contact on (search, drop, insertion), any F/T reading
    (here random, ±50 N and ±2 N m) gives the same action and the same new state, bit for bit:
    the reading only detects the contact. hybrid_spiral (its force loop) reads it."""
    rng = np.random.default_rng(0)
    touch = int(np.argmax(recorded["old_mode"] == SEARCH))
    checked = {}
    for name in ("position_spiral", "hybrid_spiral"):
        policy = baselines.make(name, ENV)
        state, differ = None, []
        for k in range(len(recorded["actions"])):
            obs, start = _observation(recorded, k), np.array([k == 0])
            if k > touch:
                fake = {**obs, "wrench": rng.normal(0.0, [50.0] * 3 + [2.0] * 3)}
                a_fake, s_fake = policy.predict(fake, np.array(state, copy=True), start)
            action, state = policy.predict(obs, state, start)
            if k > touch:
                differ.append(not (np.array_equal(a_fake, action)
                                   and np.array_equal(s_fake, state)))
        checked[name] = np.array(differ)
    assert len(checked["position_spiral"]) > 400
    assert not checked["position_spiral"].any()
    assert checked["hybrid_spiral"].mean() > 0.9


def test_its_gains_are_hybrid_spirals_without_the_force_loop() -> None:
    """The same gains and defaults as hybrid_spiral, less the force loop's four; naming one of
    those is refused, not ignored."""
    ours = {f.name: f.default for f in dataclasses.fields(PositionSpiralGains)}
    spiral = {f.name: f.default for f in dataclasses.fields(HybridSpiralGains)}
    loop = {"stiffness", "crossover_ratio", "integral_limit", "integral_limit_moment"}
    assert ours == {k: v for k, v in spiral.items() if k not in loop}
    assert ours["speed"] == 0.007  # the spiral's insertion speed, not hybrid_force_position's
    with pytest.raises(InvalidGain, match="crossover_ratio"):
        baselines.make("position_spiral", ENV, crossover_ratio=0.1)
    policy = baselines.make("position_spiral", ENV)
    assert not policy.force_gains(np.eye(6)).any()
