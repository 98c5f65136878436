"""Smoke tests of the benchmarks: they run, check their own numbers, and report honestly."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

BENCH_ROBOT = Path(__file__).parents[1] / "benchmarks" / "bench_robot.py"
QUICK = ["--calls", "3", "--repeat", "2"]


def _load_bench_robot():
    spec = importlib.util.spec_from_file_location("bench_robot", BENCH_ROBOT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bench_robot_runs_as_a_script():
    """A few calls, no ratio target (timing a loaded machine is not what this tests)."""
    result = subprocess.run(
        [sys.executable, str(BENCH_ROBOT), *QUICK, "--target", "inf"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    out = result.stdout
    for row in ("inertia(q)", "bias(q, qd)", "jacobian('flange', q)", "dynamics.rnea"):
        assert row in out
    # the raw side says what it measures
    assert "mj_kinematics + mj_comPos + mj_crb + mj_fullM" in out
    assert "mj_comVel + mj_rne" in out and "mj_jacSite" in out
    assert "skipped" not in out


def test_bench_robot_main_returns_1_when_a_ratio_misses_the_target(capsys):
    bench = _load_bench_robot()
    assert bench.main([*QUICK, "--target", "1e-9"]) == 1
    assert "MISSED" in capsys.readouterr().out


BENCH_STEP = Path(__file__).parents[1] / "benchmarks" / "bench_step.py"


def test_bench_step_writes_only_its_section_with_the_targets_it_measured(tmp_path):
    """A tiny run on one env: its section replaces the old one, the other sections stay, and
    the issue-21 target lines say met or missed for the numbers of that run."""
    out = tmp_path / "benchmarks.md"
    out.write_text("# Benchmarks\n\n## env.step and predict\n\nold\n\n## Other\n\nkept\n")
    result = subprocess.run(
        [
            sys.executable,
            str(BENCH_STEP),
            "--env",
            "cir_gym/JointTracking-v2",
            "--steps",
            "3",
            "--repeat",
            "1",
            "--batch",
            "2",
            "--num-envs",
            "2",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    text = out.read_text()
    assert "old" not in text and "## Other\n\nkept" in text
    assert text.count("## env.step and predict") == 1
    for line in (
        "- cir_gym/JointTracking-v2: overhead",
        "- pd_gravity: predict(1 obs)",
        "- computed_torque: predict(1 obs)",
    ):
        got = [row for row in text.splitlines() if row.startswith(line)]
        assert len(got) == 1 and got[0].split(": ")[-1].split(";")[0] in ("met", "missed"), got
    assert "| computed_torque | cir_gym/JointTracking-v2 |" in text


def _load_bench_step():
    sys.path.insert(0, str(BENCH_STEP.parent))  # its sibling _sections module
    spec = importlib.util.spec_from_file_location("bench_step", BENCH_STEP)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bench_step_replays_the_physics_of_the_states_the_env_visited():
    """The tape holds the env's own mj_step calls (frame_skip physics steps per env step, on
    the contact states it met); a recorded state restored and stepped gives the next recorded
    state bit for bit, and the timed loop replays the recorded steps."""
    import gymnasium as gym
    import mujoco
    import numpy as np

    bench = _load_bench_step()
    env = gym.make("cir_gym/PegInHole-v2")
    u = env.unwrapped
    mj_step = mujoco.mj_step
    mine, tape = bench.recorded_step_loop(env, 5, 2)
    assert mujoco.mj_step is mj_step  # restored
    assert len(tape.segments) == 2 and all(e == 5 for *_, e in tape.segments)
    assert tape.steps_per_env_step() == u.frame_skip
    states, nsteps = tape.segments[0].states, tape.segments[0].nsteps
    m, data, recorded = u.model, mujoco.MjData(u.model), mujoco.MjData(u.model)
    full = int(mujoco.mjtState.mjSTATE_INTEGRATION)
    physics = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)  # time, qpos, qvel, act, history, ...
    got, want = (np.empty(mujoco.mj_stateSize(m, physics)) for _ in range(2))
    for i in range(len(states) - 1):
        mujoco.mj_setState(m, data, states[i], full)
        mujoco.mj_step(m, data, nsteps[i])
        mujoco.mj_getState(m, data, got, physics)
        mujoco.mj_setState(m, recorded, states[i + 1], full)
        mujoco.mj_getState(m, recorded, want, physics)
        np.testing.assert_array_equal(got, want)
    assert mine() > 0 and bench.replay_loop(tape)() > 0
    env.close()


def test_bench_step_driven_row_times_the_contact_phase_it_recorded():
    """A driven row: the recording pass takes the controller's actions after the untimed
    warm-up and is in contact (PegInHole's zero-action row never is); the timed loop replays
    those actions, so its physics is the recorded physics, state for state."""
    import gymnasium as gym
    import mujoco
    import numpy as np

    from cir_gym import baselines

    bench = _load_bench_step()
    env_id = "cir_gym/PegInHole-v2"
    name, warmup = bench.DRIVEN[env_id]
    env = gym.make(env_id)
    u = env.unwrapped
    mine, tape = bench.recorded_step_loop(env, 4, 2, baselines.make(name, env_id), warmup)
    m, data = u.model, mujoco.MjData(u.model)
    full = int(mujoco.mjtState.mjSTATE_INTEGRATION)
    touching = []
    for segment in tape.segments:
        # the timed steps only, no warm-up (a torque period is one mj_step call of frame_skip)
        assert sum(segment.nsteps) == 4 * u.frame_skip
        for state in segment.states:
            mujoco.mj_setState(m, data, state, full)
            mujoco.mj_forward(m, data)
            touching.append(data.ncon > 0)
    assert np.mean(touching) >= 0.75  # the peg on the block (it bounces: some steps lift off)
    again = bench.PhysicsTape(m)
    for _ in range(2):
        mine.prime()  # the replayed warm-up, off the tape as in the recording
        with again:
            mine()
            again.cut(4)
    for a, b in zip(tape.segments, again.segments, strict=True):
        assert sum(a.nsteps) == sum(b.nsteps) == 4 * u.frame_skip
        for x, y in zip(a.states, b.states, strict=True):
            np.testing.assert_array_equal(x, y)
    _, zero_tape = bench.recorded_step_loop(env, 4, 1)
    mujoco.mj_setState(m, data, zero_tape.segments[0].states[0], full)
    mujoco.mj_forward(m, data)
    assert data.ncon == 0  # the zero action from the reset: in the air
    env.close()


def test_bench_step_driven_loop_resets_between_trials_off_the_tape():
    """Short episodes (100 steps, warm-up 50, trials of 30): the recording resets between
    trials, each segment holds exactly its 30 timed steps (no reset or warm-up on the tape),
    the replay plays them state for state, and a call beyond the recorded ones is an error."""
    import gymnasium as gym
    import mujoco
    import numpy as np
    import pytest

    from cir_gym import baselines

    bench = _load_bench_step()
    env_id = "cir_gym/AdmittanceContact-v2"
    env = gym.make(env_id, episode_duration=0.2, max_episode_steps=100)  # 500 Hz
    u = env.unwrapped
    policy = baselines.make("admittance", env_id, env_kwargs={"episode_duration": 0.2})
    mine, tape = bench.recorded_step_loop(env, 30, 3, policy, 50)
    assert [segment.env_steps for segment in tape.segments] == [30] * 3
    assert [sum(segment.nsteps) for segment in tape.segments] == [30 * u.frame_skip] * 3
    again = bench.PhysicsTape(u.model)
    for _ in range(3):
        mine.prime()
        with again:
            again.cut(30 if mine() > 0 else 0)
    for a, b in zip(tape.segments, again.segments, strict=True):
        for x, y in zip(a.states, b.states, strict=True):
            np.testing.assert_array_equal(x, y)
    with pytest.raises(RuntimeError, match="recorded actions"):
        mine()  # a fourth call: its reset's warm-up already runs out
    with pytest.raises(ValueError, match="fewer than steps=60"):
        bench.step_loop(env, 60, warmup=50)
    reacher = gym.make("Reacher-v5")  # 50 steps an episode, 100 asked: calls end early
    assert bench.step_loop(reacher, 100)() > 0 and bench.step_loop(reacher, 100, count=True)() == 50
    assert mujoco.mj_step is bench.mujoco.mj_step
    env.close()


BENCH_BOUND = Path(__file__).parents[1] / "benchmarks" / "bench_leaderboard_bound.py"


def test_leaderboard_bound_counts_every_physics_step_of_a_job():
    """One short job: the recorder sees frame_skip physics steps per env step (the evaluator
    runs sequentially), restores mujoco.mj_step, and the replayed physics is part of the
    evaluator's own time."""
    import mujoco

    sys.path.insert(0, str(BENCH_BOUND.parent))
    spec = importlib.util.spec_from_file_location("bench_leaderboard_bound", BENCH_BOUND)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    mj_step = mujoco.mj_step
    job = ("cir_gym/JointTracking-v2", "exact model", {"episode_duration": 0.05}, "pd_gravity")
    r = bench.run_job(job, episodes=2, seed=1000, repeat=1)
    assert mujoco.mj_step is mj_step
    assert r["env_steps"] == 2 * 25 and r["physics_steps"] == 2 * r["env_steps"]
    assert 0 < r["physics_s"] < r["total_s"]


def test_tape_of_every_model_keeps_one_segment_per_episode_with_its_model():
    """PhysicsTape() (bench_leaderboard_bound's): a segment per episode (time going back),
    each on a copy of the model as it was then; a replayed segment costs > 0 s."""
    import gymnasium as gym
    import mujoco
    import numpy as np

    sys.path.insert(0, str(BENCH_STEP.parent))
    from _tape import PhysicsTape, replay_seconds

    env = gym.make("cir_gym/JointTracking-v2")
    u = env.unwrapped
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    mj_step = mujoco.mj_step
    with PhysicsTape() as tape:
        for seed in (0, 1):
            env.reset(seed=seed)
            for _ in range(3):
                env.step(zero)
    assert mujoco.mj_step is mj_step
    assert [len(s.states) for s in tape.segments] == [3, 3]
    assert tape.physics_steps() == 2 * 3 * u.frame_skip
    assert all(s.model is not u.model for s in tape.segments)  # copies
    assert replay_seconds(tape.segments[0]) >= 0.0
    env.close()


BENCH_VECTOR = Path(__file__).parents[1] / "benchmarks" / "bench_vector.py"


def test_bench_vector_times_a_batched_env_against_sync_side_by_side(monkeypatch):
    """One row per (env, copies) with positive rates and the ratios of those rates."""
    monkeypatch.syspath_prepend(str(BENCH_VECTOR.parent))  # its sibling _sections module
    spec = importlib.util.spec_from_file_location("bench_vector", BENCH_VECTOR)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    rows = module.bench_throughput([2], steps=8, repeat=1, env_ids=["cir_gym/CartesianTracking-v1"])
    table = [row for row in rows if row.startswith("| cir_gym/")]
    assert len(table) == 1
    cells = [c.strip().replace(",", "") for c in table[0].strip("|").split("|")]
    env_id, copies, sync, vec, ratio, raw, vs_raw, sync_wall, wall2, ratio_wall = cells
    assert (env_id, copies) == ("cir_gym/CartesianTracking-v1", "2")
    rates = [float(v) for v in (sync, vec, raw, sync_wall, wall2)]
    assert all(r > 0 for r in rates)
    assert float(ratio) == pytest.approx(float(vec) / float(sync), rel=0.05, abs=0.051)
    assert float(ratio_wall) == pytest.approx(float(wall2) / float(sync_wall), rel=0.05, abs=0.051)
    assert float(vs_raw) == pytest.approx(float(vec) / float(raw), rel=0.05, abs=0.0051)
