"""scripts/sweep.py: grid expansion, the tidy table, faults and resumption, Ray, training tasks.

Episodes last 0.1 s (50 steps): the sweep machinery is under test, not the controllers. The
default run keeps one local-pool fault/resume test (a task that raises, a worker that is
killed); the Ray tests (a Ray instance takes ~20 s to start here) and the training and
killed-driver tests are marked slow.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from cir_gym.scoring.sweep import (
    GridError,
    expand,
    read_table,
    run_sweep,
    run_task,
    task_id,
    write_table,
)

ENV = "cir_gym/JointTracking-v2"
SHORT = {"episode_duration": 0.1}
FLAKY = f"{Path(__file__).resolve().parent / 'sweep_faults.py'}:flaky"
#: columns that differ between runs of the same task (wall time, which process ran it)
VOLATILE = {"seconds", "worker", "attempts"}


def small_grid(**overrides) -> dict:
    block = {
        "envs": [ENV],
        "policies": ["computed_torque", "pd_gravity"],
        "seed": 0,
        "episodes": 2,
        "env_kwargs": {"payload_mass": [0.0, 3.0]},
        "env_overrides": SHORT,
        **overrides,
    }
    return {"evaluate": block}


def episodes_of(rows: list[dict]) -> dict[tuple, dict]:
    """Per-episode rows keyed by (variant, policy, gains, episode seed), volatile columns out."""
    return {
        (r["variant"], r["policy"], r.get("gain.omega_n"), r["episode_seed"]): {
            k: v for k, v in r.items() if k not in VOLATILE
        }
        for r in rows
    }


# ---------------------------------------------------------------------- the grid
def test_expand_makes_one_task_per_combination_and_seed_chunk():
    grid = small_grid(
        episodes=5, episodes_per_task=2, gains={"computed_torque": {"omega_n": [20.0, 40.0]}}
    )
    tasks = expand(grid)
    # computed_torque: 2 gain sets, pd_gravity: 1; × 2 payloads × 3 chunks (2 + 2 + 1 episodes)
    assert len(tasks) == (2 + 1) * 2 * 3
    chunks = sorted({(t["seed"], t["episodes"]) for t in tasks})
    assert chunks == [(0, 2), (2, 2), (4, 1)]
    assert {t["variant"] for t in tasks} == {"payload_mass=0.0", "payload_mass=3.0"}
    assert all(t["env_kwargs"]["episode_duration"] == 0.1 for t in tasks)
    ids = [t["task_id"] for t in tasks]
    assert len(set(ids)) == len(ids)
    assert ids == [t["task_id"] for t in expand(grid)]  # stable: the key of resumption
    assert task_id({"a": 1, "b": 2}) == task_id({"b": 2, "a": 1})


def test_all_policies_pair_an_agent_with_its_own_objective_only():
    """policies: all on RedundantIK's leaderboard variants: every controller on every
    objective, a shipped agent only on the objective it was trained for (as the leaderboard);
    an agent named explicitly runs where it is asked to."""
    rik = "cir_gym/RedundantIK-v4"
    grid = {"evaluate": {"envs": [rik], "policies": "all", "episodes": 1,
                         "env_kwargs": "leaderboard"}}
    pairs = {(t["policy"], t["variant"]) for t in expand(grid)}
    assert {("clik", v) for v in ("manipulability", "obstacle", "joint limits")} <= pairs
    ppo, obstacle = "agent:ppo@RedundantIK-v3", "agent:ppo_obstacle@RedundantIK-v3"
    assert {v for p, v in pairs if p == ppo} == {"manipulability"}
    assert {v for p, v in pairs if p == obstacle} == {"obstacle"}
    grid["evaluate"]["policies"] = [ppo]
    assert len(expand(grid)) == 3


def test_expand_leaderboard_variants_and_explicit_kwargs():
    import cir_gym

    tasks = expand(
        {
            "evaluate": {
                "envs": [ENV],
                "policies": ["pd_gravity"],
                "episodes": 1,
                "env_kwargs": "leaderboard",
                "env_overrides": SHORT,
            }
        }
    )
    variants = cir_gym.ENVIRONMENTS[ENV][0].leaderboard_variants
    assert [t["variant"] for t in tasks] == list(variants)
    tasks = expand(
        {
            "evaluate": {
                "envs": [ENV],
                "policies": ["pd_gravity"],
                "episodes": 1,
                "env_kwargs": [{"viscous_friction": [0.5] * 7}, {}],
            }
        }
    )
    assert tasks[0]["env_kwargs"] == {"viscous_friction": [0.5] * 7}  # a list value, not an axis
    assert tasks[1]["variant"] == "default arguments"


@pytest.mark.parametrize(
    "grid, needle",
    [
        ({"evaluate": {"envs": ["cir_gym/Nope-v0"]}}, "unknown environment"),
        ({"evaluate": {"envs": [ENV], "policies": ["nope"]}}, "unknown policy 'nope'"),
        (
            {"evaluate": {"envs": [ENV], "env_kwargs": {"payload": [1]}}},
            "no argument(s) ['payload']",
        ),
        (
            {
                "evaluate": {
                    "envs": [ENV],
                    "policies": ["pd_gravity"],
                    "gains": {"pd_gravity": {"omega_n": [1]}},
                }
            },
            "no gain(s) ['omega_n']",
        ),
        ({"evaluate": {"envs": [ENV], "episodes": 0}}, "'episodes' must be an integer >= 1"),
        ({"evaluate": {"envs": [ENV], "sedes": 3}}, "unknown key(s) ['sedes']"),
        ({"evalute": {}}, "unknown key(s) ['evalute']"),
        ({"train": {"envs": [ENV], "algos": ["dqn"]}}, "unknown algorithm 'dqn'"),
        (
            {"train": {"envs": [ENV], "hyperparams": [{"name": "a"}, {"name": "a"}]}},
            "share run directories",
        ),
    ],
)
def test_a_bad_grid_is_a_clear_error(grid, needle):
    with pytest.raises(GridError) as err:
        expand(grid)
    assert needle in str(err.value)


# ---------------------------------------------------------------------- the table
@pytest.mark.parametrize("fmt", ["parquet", "csv"])
def test_table_round_trip_keeps_types_and_missing_cells(tmp_path, fmt):
    if fmt == "parquet":
        pytest.importorskip("pyarrow")
    rows = [
        {
            "task_id": "a",
            "status": "ok",
            "episode_seed": 3,
            "return": -1.5,
            "success": True,
            "env.link_mass_scale": [1.0, 2.0],
            "metric.rms_error": 0.01,
        },
        {"task_id": "b", "status": "failed", "error": "RuntimeError: x | y"},
    ]
    path = write_table(rows, tmp_path, fmt)
    assert path.suffix == f".{fmt}"
    back = read_table(tmp_path)
    assert back[0]["episode_seed"] == 3 and back[0]["return"] == -1.5
    assert back[0]["success"] is True and back[0]["metric.rms_error"] == 0.01
    assert json.loads(back[0]["env.link_mass_scale"]) == [1.0, 2.0]
    assert back[1]["error"] == "RuntimeError: x | y" and back[1]["return"] is None
    assert list(back[0])[:3] == ["task_id", "status", "error"]


def test_a_task_gives_the_evaluators_episodes(tmp_path):
    from cir_gym.evaluation import evaluate
    from cir_gym.scoring.policies import make_policy

    task = next(
        t
        for t in expand(small_grid(policies=["pd_gravity"]))
        if t["env_kwargs"]["payload_mass"] == 3.0
    )
    rows = run_task(task, str(tmp_path))["rows"]
    ref = evaluate(
        make_policy(ENV, "pd_gravity", task["env_kwargs"], {}), ENV, 1, 0, **task["env_kwargs"]
    )
    assert len(rows) == 1 and rows[0]["episode_seed"] == 0
    assert rows[0]["metric.rms_error"] == ref.episodes[0].metrics["rms_error"]
    assert rows[0]["return"] == ref.episodes[0].episode_return
    assert rows[0]["env.payload_mass"] == 3.0 and rows[0]["policy"] == "pd_gravity"


# ---------------------------------------------------------------------- faults, resumption
def fault_grid(tmp_path: Path) -> dict:
    """pd_gravity on 2 episodes (2 tasks), a task that raises while ``raise.flag`` exists and
    one whose first attempt kills its worker process."""

    def block(policy: str, episodes: int, gains: dict | None = None) -> dict:
        return {
            "envs": [ENV],
            "policies": [policy],
            "seed": 0,
            "episodes": episodes,
            "env_kwargs": SHORT,
            "gains": {policy: gains} if gains else {},
        }

    log = str(tmp_path / "attempts.log")
    return {
        "evaluate": [
            block("pd_gravity", 2),
            block(FLAKY, 1, {"mode": "raise", "flag": str(tmp_path / "raise.flag"), "log": log}),
            block(
                FLAKY, 1, {"mode": "kill_once", "flag": str(tmp_path / "killed.flag"), "log": log}
            ),
        ]
    }


def attempts(tmp_path: Path, mode: str) -> int:
    return (tmp_path / "attempts.log").read_text().split().count(mode)


def check_fault_and_resume(tmp_path: Path, **run) -> None:
    """First run: the killed task is retried and finishes, the raising one is recorded as
    failed after 1 + 1 attempts, the sweep completes. Second run (the fault gone): only the
    failed task runs; every finished task file is untouched."""
    grid, out = fault_grid(tmp_path), tmp_path / "out"
    (tmp_path / "raise.flag").touch()
    first = run_sweep(grid, out, retries=1, progress=False, **run)
    assert (first.tasks, first.ran, first.failed) == (4, 4, 1)
    assert attempts(tmp_path, "raise") == 2 and attempts(tmp_path, "kill_once") == 2
    rows = read_table(out)
    failed = [r for r in rows if r["status"] == "failed"]
    assert len(failed) == 1 and "injected failure" in failed[0]["error"]
    assert failed[0]["gain.mode"] == "raise"
    ok = [r for r in rows if r["status"] == "ok"]
    assert sorted(r.get("gain.mode") or "" for r in ok) == ["", "", "kill_once"]
    files = {p.name: (p.stat().st_mtime_ns, p.read_text()) for p in (out / "tasks").glob("*")}

    (tmp_path / "raise.flag").unlink()
    second = run_sweep(grid, out, retries=1, progress=False, **run)
    assert (second.skipped, second.ran, second.failed) == (3, 1, 0)
    assert attempts(tmp_path, "raise") == 3 and attempts(tmp_path, "kill_once") == 2
    after = {p.name: (p.stat().st_mtime_ns, p.read_text()) for p in (out / "tasks").glob("*")}
    changed = [n for n in files if after[n] != files[n]]
    assert changed == [f"{failed[0]['task_id']}.json"]  # nothing finished was rewritten
    rows2 = read_table(out)
    assert all(r["status"] == "ok" for r in rows2) and len(rows2) == 4
    for key, row in episodes_of(ok).items():
        assert episodes_of(rows2)[key] == row


def test_local_pool_survives_a_raising_task_and_a_killed_worker_and_resumes(tmp_path):
    check_fault_and_resume(tmp_path, workers=2)


@pytest.mark.slow
def test_a_killed_worker_without_retries_is_recorded_and_the_rerun_finishes_it(tmp_path):
    grid = {"evaluate": fault_grid(tmp_path)["evaluate"][2]}
    first = run_sweep(grid, tmp_path / "out", workers=1, retries=0, progress=False)
    assert first.failed == 1
    record = json.loads(next((tmp_path / "out" / "tasks").glob("*.json")).read_text())
    assert record["status"] == "failed" and "worker process died" in record["error"]
    second = run_sweep(grid, tmp_path / "out", workers=1, retries=0, progress=False)
    assert (second.ran, second.failed) == (1, 0)
    assert read_table(tmp_path / "out")[0]["status"] == "ok"


@pytest.mark.slow
def test_a_killed_driver_loses_no_finished_task(tmp_path):
    """``cir-gym sweep`` killed (SIGKILL, with its workers) once some tasks are written: the
    re-run skips exactly those and finishes the rest."""
    grid = tmp_path / "grid.yaml"
    grid.write_text(yaml.safe_dump(small_grid(episodes=6, env_overrides={"episode_duration": 1.0})))
    out = tmp_path / "out"
    cmd = [
        sys.executable,
        "-m",
        "cir_gym.cli",
        "sweep",
        str(grid),
        "--out",
        str(out),
        "--workers",
        "2",
    ]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    deadline = time.monotonic() + 120
    while len(list((out / "tasks").glob("*.json"))) < 3 and time.monotonic() < deadline:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    written = {p.name: p.read_text() for p in (out / "tasks").glob("*.json")}
    assert 3 <= len(written) < 24, "kill it mid-sweep"
    summary = run_sweep(grid, out, workers=2, progress=False)
    assert (summary.skipped, summary.ran) == (len(written), 24 - len(written))
    for name, text in written.items():
        assert (out / "tasks" / name).read_text() == text
    assert len(read_table(out)) == 24


# ---------------------------------------------------------------------- Ray
@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray")
    # a loaded 2-core machine can take longer than Ray's default to register the raylet
    os.environ.setdefault("RAY_raylet_start_wait_time_s", "120")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.mark.slow
def test_ray_gives_the_same_episodes_as_the_local_pool(tmp_path, local_ray):
    grid = small_grid(gains={"computed_torque": {"omega_n": [20.0, 40.0]}})
    local = run_sweep(grid, tmp_path / "local", workers=2, progress=False)
    on_ray = run_sweep(grid, tmp_path / "ray", ray="auto", progress=False)
    assert local.ran == on_ray.ran == 12 and local.failed == on_ray.failed == 0
    a, b = episodes_of(read_table(tmp_path / "local")), episodes_of(read_table(tmp_path / "ray"))
    assert len(a) == 12 and a == b
    workers = {json.loads(p.read_text())["worker"] for p in (tmp_path / "ray/tasks").glob("*")}
    assert len(workers) >= 1 and all(":" in w for w in workers)


@pytest.mark.slow
def test_ray_retries_and_records_failures_then_resumes(tmp_path, local_ray):
    check_fault_and_resume(tmp_path, ray="auto")


# ---------------------------------------------------------------------- training tasks
def tiny_hyperparams(path: Path) -> Path:
    """A PPO file whose default entry trains 256 steps in seconds (as tests/test_agents.py)."""
    default = {
        "policy": "MlpPolicy",
        "n_timesteps": 256,
        "n_envs": 2,
        "normalize": {"norm_obs": True, "norm_reward": True},
        "n_steps": 64,
        "batch_size": 64,
        "n_epochs": 2,
        "policy_kwargs": {"net_arch": [16, 16], "activation_fn": "tanh", "log_std_init": -1.0},
        "eval_freq": 128,
        "n_eval_episodes": 1,
        "checkpoint_freq": 128,
        "residual": {"scale": 0.25},
    }
    path.write_text(yaml.safe_dump({"default": default}))
    return path


@pytest.fixture(scope="module")
def training_sweep(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("train_sweep")
    grid = {
        "train": {
            "envs": [ENV],
            "algos": ["ppo"],
            "seeds": [0, 1],
            "hyperparams_path": str(tiny_hyperparams(tmp / "ppo.yml")),
            "hyperparams": [{"name": "lr3", "learning_rate": 0.001}],
            "env_kwargs": SHORT,
            "evaluate": {"episodes": 2, "seed": 1000},
        }
    }
    summary = run_sweep(grid, tmp / "out", workers=2, progress=False)
    return tmp / "out", summary


@pytest.mark.slow
def test_training_tasks_write_seed_runs_and_evaluate_them(training_sweep):
    out, summary = training_sweep
    assert (summary.ran, summary.failed) == (2, 0)
    rows = read_table(out)
    assert sorted({(r["train_seed"], r["run_dir"]) for r in rows}) == [
        (k, f"runs/JointTracking-v2/ppo_lr3/seed_{k}") for k in (0, 1)
    ]
    assert len(rows) == 4 and all(r["policy"] == "train:ppo_lr3" for r in rows)
    for k in (0, 1):
        config = yaml.safe_load(
            (out / f"runs/JointTracking-v2/ppo_lr3/seed_{k}/config.yml").read_text()
        )
        assert config["seed"] == k and config["hyperparams"]["learning_rate"] == 0.001
        assert config["n_timesteps"] == 256
    # different training seeds learned different policies
    by_seed = {r["train_seed"]: r["metric.rms_error"] for r in rows if r["episode_seed"] == 1000}
    assert by_seed[0] != by_seed[1]


@pytest.mark.slow
def test_leaderboard_reports_training_seeds_with_iqm(training_sweep, tmp_path, monkeypatch):
    """The sweep's two seed runs: in ``leaderboard --from`` as runs over seeds, and, shipped
    as ``<name>/seed_<k>``, in the leaderboard's multi-seed table (agents.report.seed_table)."""
    from cir_gym import agents
    from cir_gym.scoring.leaderboard import leaderboard_from, multi_seed_table

    out, _ = training_sweep
    md = leaderboard_from(out, tmp_path / "page").read_text()
    assert "Training runs over seeds" in md and "| train:ppo_lr3 | 2 |" in md
    assert "train:ppo_lr3 seed 0" in md and "train:ppo_lr3 seed 1" in md
    trained = tmp_path / "trained" / "JointTracking-v2"
    shutil.copytree(out / "runs" / "JointTracking-v2" / "ppo_lr3", trained / "ppo_lr3")
    monkeypatch.setattr(agents, "TRAINED_DIR", tmp_path / "trained")
    table = multi_seed_table(ENV, SHORT, episodes=2, seed=1000)
    row = next(r for r in table.splitlines() if r.startswith("| ppo_lr3 "))
    assert row.split("|")[2].strip() == "2"
    iqm = float(row.split("|")[3])
    scores = np.sort([r["metric.rms_error"] for r in read_table(out)])
    assert iqm == pytest.approx(scores[1:3].mean(), rel=5e-3)  # IQM of 4 scores: the middle 2


@pytest.mark.parametrize("path", sorted((Path(__file__).parents[1] / "sweeps").glob("*.yaml")))
def test_every_shipped_grid_expands(path):
    from cir_gym.scoring.sweep import load_grid

    tasks = expand(load_grid(path))
    assert tasks and len({t["task_id"] for t in tasks}) == len(tasks)


SHIPPED_GRIDS = sorted((Path(__file__).parents[1] / "sweeps").glob("*.yaml"))


def short(env_id: str) -> dict:
    """:data:`SHORT` episodes, but RedundantIK's own (its obstacle variant places an obstacle
    the links sweep past in a full lap only)."""
    return {} if "RedundantIK" in env_id else SHORT


def tiny_budget(grid: dict, tmp: Path) -> dict:
    """A shipped grid at a tiny budget: 1 episode of 0.1 s (:func:`short`) per evaluation,
    one block per environment, training runs of
    256 steps (:func:`tiny_hyperparams`) scored on 1 short episode; every environment, policy,
    variant and gain of the grid kept."""
    grid = dict(grid)
    blocks = grid.get("evaluate")
    if blocks is not None:
        grid["evaluate"] = [
            {**b, "envs": [env], "episodes": 1, "episodes_per_task": 1,
             "env_overrides": {**(b.get("env_overrides") or {}), **short(env)}}
            for b in (blocks if isinstance(blocks, list) else [blocks])
            for env in ([b["envs"]] if isinstance(b["envs"], str) else b["envs"])
        ]
    blocks = grid.get("train")
    if blocks is not None:
        grid["train"] = [
            {**b, "timesteps": 256, "hyperparams_path": str(tiny_hyperparams(tmp / "ppo.yml")),
             "env_overrides": {**(b.get("env_overrides") or {}), **SHORT},
             "evaluate": {"episodes": 1, "seed": 1000}}
            for b in (blocks if isinstance(blocks, list) else [blocks])
        ]
    return grid


#: grids too long for the default run even on a tiny budget (minutes): the leaderboard as a
#: grid (181 tasks, RedundantIK's full-length episodes) and the training grid (6 runs)
SLOW_GRIDS = ("leaderboard", "train_seeds")


@pytest.mark.parametrize(
    "path",
    [pytest.param(p, marks=pytest.mark.slow) if p.stem in SLOW_GRIDS else p
     for p in SHIPPED_GRIDS],
    ids=[p.stem for p in SHIPPED_GRIDS],
)
def test_every_shipped_grid_runs_clean_on_a_tiny_budget(path, tmp_path):
    """Each grid of sweeps/ runs with no failed task (``policies: all`` once expanded to
    ``tuned:*`` names that the worker took for ``module:callable`` factories);
    :data:`SLOW_GRIDS` are marked slow."""
    from cir_gym.scoring.sweep import load_grid

    grid = tiny_budget(load_grid(path), tmp_path)
    summary = run_sweep(grid, tmp_path / "out", workers=2, retries=0, progress=False)
    failed = [r for r in read_table(tmp_path / "out") if r["status"] != "ok"]
    assert summary.failed == 0 and not failed, failed[:3]
    assert summary.ran == summary.tasks == len(expand(grid))


def test_all_policies_keep_a_tuned_law_to_the_settings_it_was_tuned_for():
    from cir_gym.scoring.policies import has_tuned_gains

    tasks = expand(small_grid(policies="all", env_kwargs={"payload_mass": [0.0, 1.0]}))
    # tuned on 4-s episodes, its gains hold on SHORT ones (the start of the same episode)
    tuned = {(t["policy"], t["env_kwargs"]["payload_mass"]) for t in tasks
             if t["policy"].startswith("tuned:")}
    assert tuned and all(has_tuned_gains(ENV, p, {"payload_mass": m}) for p, m in tuned)
    assert {m for _, m in tuned} == {0.0}  # nothing tuned for 1 kg
    with pytest.raises(GridError, match=r"no gains tuned for .* payload_mass=1\.0"):
        expand(small_grid(policies=["tuned:pd_gravity"], env_kwargs={"payload_mass": [1.0]}))


def test_ray_stays_optional():
    """Neither the package nor the command line imports Ray (or pyarrow) until a sweep asks."""
    code = (
        "import sys, cir_gym, cir_gym.baselines, cir_gym.agents, cir_gym.cli,"
        " cir_gym.scoring.sweep, cir_gym.scoring.leaderboard;"
        "print(sorted(m for m in ('ray', 'pyarrow') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    ).stdout
    assert out.strip() == "[]"


@pytest.mark.slow
def test_a_training_task_killed_mid_run_resumes_from_its_checkpoint(training_sweep, tmp_path):
    """A seed's run as a kill at 128 of 256 steps leaves it (checkpoint at 128, no final model,
    no task file): the re-run resumes it from that checkpoint and skips the other seed."""
    import yaml as _yaml

    src, _ = training_sweep
    out = tmp_path / "out"
    shutil.copytree(src, out)
    run = out / "runs/JointTracking-v2/ppo_lr3/seed_0"
    for f in ("model.zip", "meta.json", "checkpoints/model_256_steps.zip"):
        (run / f).unlink()
    task = next(
        p
        for p in (out / "tasks").glob("*.json")
        if json.loads(p.read_text())["task"]["train_seed"] == 0
    )
    record = json.loads(task.read_text())
    task.unlink()
    params = record["task"]
    grid = {
        "train": {
            "envs": [params["env_id"]],
            "algos": ["ppo"],
            "seeds": [0, 1],
            "hyperparams_path": params["hyperparams_path"],
            "hyperparams": [{"name": "lr3", **params["hyperparams"]}],
            "env_kwargs": params["env_kwargs"],
            "evaluate": {"episodes": 2, "seed": 1000},
        }
    }
    summary = run_sweep(grid, out, workers=1, progress=False)
    assert (summary.skipped, summary.ran, summary.failed) == (1, 1, 0)
    meta = json.loads((run / "meta.json").read_text())
    assert meta["timesteps"] == 256 and meta["finished"] and (run / "model.zip").is_file()
    # resumed, not restarted: the curve keeps the first session's rows (a restart removes it)
    curve = (run / "learning_curve.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in curve] == [128, 256, 256]
    assert _yaml.safe_load((run / "config.yml").read_text())["seed"] == 0


@pytest.mark.slow
def test_a_training_run_on_another_host_comes_back_to_the_driver(training_sweep, tmp_path):
    """A training task whose driver is elsewhere (a multi-node Ray cluster without a shared
    filesystem) returns its run directory; the driver unpacks it under its own ``out``."""
    from cir_gym import agents
    from cir_gym.scoring.sweep import unpack_run

    src, _ = training_sweep
    record = json.loads(next((src / "tasks").glob("*.json")).read_text())
    task = record["task"]
    node = tmp_path / "node"  # the worker node's copy of --out
    result = run_task(task, str(node), driver_host="not-" + __import__("socket").gethostname())
    assert isinstance(result["archive"], bytes)
    driver = tmp_path / "driver"
    run_dir = unpack_run(result, driver)
    assert "archive" not in result and run_dir == driver / result["rows"][0]["run_dir"]
    files = {p.relative_to(run_dir).as_posix() for p in run_dir.rglob("*") if p.is_file()}
    assert {"model.zip", "config.yml", "learning_curve.csv", "meta.json"} <= files
    assert not any(f.startswith(("checkpoints/", "tb/")) for f in files)
    from cir_gym.evaluation import evaluate

    policy = agents.load(task["env_id"], "copy", path=run_dir)  # the same agent, complete
    res = evaluate(
        policy, task["env_id"], task["eval_episodes"], task["seed"], **task["env_kwargs"]
    )
    assert [e.episode_return for e in res.episodes] == [r["return"] for r in result["rows"]]
