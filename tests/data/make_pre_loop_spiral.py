"""Write tests/data/pre_loop_spiral.npz: PegInHole-v2 observations and the actions of the
pre-loop hybrid_spiral (baselines/hybrid.py at 36b763b^, before the force loop), the fixture of
tests/test_position_spiral.py.

The old law runs in its own tree (its cir_gym and baselines) in a child process, fed each
observation of this tree's PegInHole-v2 over a pipe; its actions drive the episode. Make the
old tree first, then run this from the repository's root::

    git worktree add --detach /tmp/pspiral/wt_old 36b763b^
    python tests/data/make_pre_loop_spiral.py /tmp/pspiral/wt_old

Seed 1058 with the start 2 mm above the nominal face: the first contact at step 365, the drop
into the hole at step 623 (the spiral search between), then the insertion; 800 steps.
"""

from __future__ import annotations

import importlib.util
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np

SEED, STEPS, ENV_KWARGS = 1058, 800, {"start_height": 0.002}
OUT = Path(__file__).with_name("pre_loop_spiral.npz")


def serve(root: str) -> None:
    """The old tree's hybrid_spiral (for its PegInHole-v1: the same nominal arm, peg and hole):
    a pickled observation in, the pickled (action, state) out; None starts an episode."""
    sys.path.insert(0, root)
    import gymnasium as gym

    import cir_gym  # noqa: F401  (the old tree's)

    spec = importlib.util.spec_from_file_location(
        "cir_gym.baselines", f"{root}/baselines/__init__.py",
        submodule_search_locations=[f"{root}/baselines"])
    baselines = importlib.util.module_from_spec(spec)
    sys.modules["cir_gym.baselines"] = baselines
    spec.loader.exec_module(baselines)
    env_id = "cir_gym/PegInHole-v1"
    policy = baselines.make("hybrid_spiral", env_id, env=gym.make(env_id))
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    state, start = None, True
    while True:
        try:
            obs = pickle.load(inp)
        except EOFError:
            return
        if obs is None:
            state, start = None, True
            continue
        action, state = policy.predict(obs, state, np.array([start]))
        start = False
        pickle.dump((np.asarray(action), np.array(state)), out)
        out.flush()


def record(root: str) -> None:
    """Drive this tree's PegInHole-v2 with the old law; save observations and actions."""
    import gymnasium as gym

    import cir_gym  # noqa: F401

    env = {**os.environ, "PYTHONPATH": root}
    child = subprocess.Popen([sys.executable, __file__, "--serve", root], env=env,
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    sim = gym.make("cir_gym/PegInHole-v2", **ENV_KWARGS)
    obs, _ = sim.reset(seed=SEED)
    observations, actions, modes = [], [], []
    for _ in range(STEPS):
        pickle.dump({k: np.array(v) for k, v in obs.items()}, child.stdin)
        child.stdin.flush()
        action, state = pickle.load(child.stdout)
        observations.append(obs)
        actions.append(action)
        modes.append(np.ravel(state)[2])  # the old state: [t, z̄, mode, θ, centre, z_c]
        obs, _, terminated, truncated, _ = sim.step(action)
        assert not (terminated or truncated)
    child.stdin.close()
    child.wait()
    stacked = {k: np.stack([o[k] for o in observations]) for k in observations[0]}
    for key in ("hole_pos", "hole_quat"):  # the nominal hole: one pose per episode
        assert np.ptp(stacked[key], axis=0).max() == 0.0
        stacked[key] = stacked[key][0]
    np.savez_compressed(OUT, actions=np.stack(actions), old_mode=np.array(modes), seed=SEED,
                        start_height=ENV_KWARGS["start_height"], **stacked)
    change = np.flatnonzero(np.diff(modes)) + 1
    print(f"{OUT}: {STEPS} steps, phase changes at {change.tolist()}, "
          f"{OUT.stat().st_size} bytes")


if __name__ == "__main__":
    if sys.argv[1] == "--serve":
        serve(sys.argv[2])
    else:
        record(sys.argv[1])
