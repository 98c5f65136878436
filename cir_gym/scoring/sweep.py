"""``cir-gym sweep``: a grid of evaluations and training runs as independent tasks.

A grid file (YAML) names environments × policies (or algorithms) × seeds × environment
arguments × gains (or hyperparameter sets); :func:`expand` turns it into tasks, each a small
mapping of plain parameters, and :func:`run_sweep` runs them

* on a local pool of ``workers`` spawned processes (default), one process per slot, so a task
  that kills its process (a segfault, the OOM killer) is known and only that task is retried;
* or on a Ray cluster (``ray=ADDRESS``, ``"auto"`` or ``"local"``), where Ray schedules the
  tasks and retries them (``max_retries`` for a dead worker, ``retry_exceptions`` for an
  exception); nothing here schedules Ray's work.

A task that still fails after ``retries`` retries is recorded as failed with its error and the
sweep goes on. The driver writes every finished task at once to ``<out>/tasks/<task id>.json``
(atomically; the id is a hash of the task's parameters), so a sweep that is killed loses no
finished task and re-running it skips them (failed tasks run again). At the end the task files
of the grid are merged into one tidy table, ``<out>/results.parquet`` (``results.csv`` without
pyarrow): one row per episode with the task's parameters (``env.<argument>``, ``gain.<name>``,
``hp.<name>``) and the episode's return, length, success, divergence and metrics
(``metric.<name>``); a failed task is one row with ``status = "failed"`` and its ``error``.
``cir-gym leaderboard --from <out>`` renders it
(:func:`cir_gym.scoring.leaderboard.leaderboard_from`).

Episodes are scored by :func:`cir_gym.evaluation.evaluate` (episode ``i`` of a task reset with
seed ``first seed + i``), so splitting a seed range into tasks changes no result. Training tasks
call :func:`agents.train.train` (one run per task, run directories under ``<out>/runs`` in the
``<name>/seed_<k>`` layout that :func:`agents.train.ship` and :mod:`agents.report` read), then
evaluate the final model.

Grid file::

    evaluate:                       # a block, or a list of blocks
      envs: [cir_gym/JointTracking-v2]
      policies: [computed_torque, pd_gravity, "agent:ppo_100hz"]  # or "all" (agents only on
                                    # their own task, tuned:<law> only where it was tuned);
                                    # "plugin:<name>" (cir-gym list); or "module:factory"
      seed: 1000                    # first episode seed
      episodes: 20                  # episodes per (env, policy, arguments, gains)
      episodes_per_task: 5          # default 1: one task per episode
      env_kwargs: {payload_mass: [0.0, 3.0]}   # a list is an axis ([[...]] for a list value),
                                    # or a list of mappings, or "leaderboard" (the variants)
      env_overrides: {episode_duration: 2.0}   # added to every variant
      gains: {computed_torque: {omega_n: [20.0, 40.0]}}      # axes per controller
    train:
      envs: [cir_gym/JointTracking-v2]
      algos: [ppo]
      residual: [null, computed_torque]
      seeds: [0, 1, 2]              # training seeds (or a count)
      timesteps: 100000
      hyperparams: [{name: base}, {name: lr1e-3, learning_rate: 0.001}]
      env_kwargs: {episode_duration: 2.0}
      evaluate: {episodes: 5, seed: 1000}

A policy ``"module:callable"`` or ``"path/to/file.py:callable"`` is built by
``callable(env_id, env_kwargs, gains)`` in the worker: a user's own policy in a sweep.

Ray is optional (``pip install 'cir-gym[sweep]'``): it is imported only when ``ray`` is given.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import importlib
import importlib.util
import io
import itertools
import json
import multiprocessing
import os
import shutil
import socket
import sys
import tarfile
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from cir_gym.agents.hyperparameters import ALGORITHMS

__all__ = [
    "GridError",
    "RayUnavailable",
    "SweepSummary",
    "expand",
    "load_grid",
    "read_table",
    "run_sweep",
    "run_task",
    "task_id",
]

TABLE_STEM = "results"
#: a task's parameters that become the table's leading columns
PARAMS = (
    "task_id",
    "kind",
    "env_id",
    "variant",
    "policy",
    "algo",
    "residual",
    "hp_set",
    "train_seed",
)
#: columns first in the table, in this order (the others follow sorted)
LEADING = (
    *PARAMS[:2],
    "status",
    "error",
    *PARAMS[2:],
    "episode_seed",
    "return",
    "length",
    "success",
    "diverged",
    "terminated",
)
#: thread pools of numerical libraries in a worker: one thread each (the pool is the parallelism)
ONE_THREAD = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


class GridError(ValueError):
    """A grid file that cannot be expanded: the message names the entry and what is allowed."""


class RayUnavailable(RuntimeError):
    """``ray=ADDRESS`` or ``"auto"`` found no Ray cluster: the message says how to start one."""


# ---------------------------------------------------------------------- the grid
def load_grid(path: str | Path) -> dict[str, Any]:
    """Read a grid YAML file (a mapping with ``evaluate`` and/or ``train``)."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise GridError(f"grid file {path} does not exist")
    try:
        grid = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise GridError(f"{path}: not valid YAML: {exc}") from exc
    if not isinstance(grid, dict):
        raise GridError(f"{path}: expected a mapping with 'evaluate' and/or 'train'")
    return grid


def task_id(params: dict[str, Any]) -> str:
    """16 hex digits of the SHA-256 of the task's parameters (canonical JSON)."""
    text = json.dumps(params, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _blocks(grid: dict[str, Any], kind: str) -> list[dict[str, Any]]:
    block = grid.get(kind)
    if block is None:
        return []
    blocks = block if isinstance(block, list) else [block]
    for b in blocks:
        if not isinstance(b, dict):
            raise GridError(f"'{kind}' must be a mapping or a list of mappings, got {b!r}")
    return blocks


def _check_keys(where: str, block: dict[str, Any], allowed: Iterable[str]) -> None:
    unknown = sorted(set(block) - set(allowed))
    if unknown:
        raise GridError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")


def _env_ids(where: str, block: dict[str, Any]) -> list[str]:
    import cir_gym

    envs = block.get("envs")
    if not envs:
        raise GridError(
            f"{where}: 'envs' must list environment ids; valid: {sorted(cir_gym.ENVIRONMENTS)}"
        )
    from cir_gym.scoring.policies import PolicyError, check_env_id

    envs = [envs] if isinstance(envs, str) else list(envs)
    out = []
    for e in envs:
        try:
            out.append(check_env_id(str(e)))  # the cir_gym/ prefix optional, as on the CLI
        except PolicyError as exc:
            raise GridError(f"{where}: {exc}") from None
    return out


def _product(where: str, axes: Any) -> list[dict[str, Any]]:
    """A mapping whose list values are axes → every combination (a scalar is fixed)."""
    if axes is None:
        return [{}]
    if not isinstance(axes, dict):
        raise GridError(f"{where}: expected a mapping of name → value or [values], got {axes!r}")
    keys = list(axes)
    values = [v if isinstance(v, list) else [v] for v in axes.values()]
    for k, v in zip(keys, values, strict=True):
        if not v:
            raise GridError(f"{where}: '{k}' has an empty list of values")
    return [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*values)]


def _variants(where: str, env_id: str, spec: Any, overrides: Any) -> list[tuple[str, dict]]:
    """(variant name, env kwargs) of ``env_kwargs`` (+ ``env_overrides``), arguments checked."""
    import cir_gym
    from cir_gym.envs.base import constructor_arguments

    cls = cir_gym.ENVIRONMENTS[env_id][0]
    if spec == "leaderboard":
        named = list(getattr(cls, "leaderboard_variants", {"default": {}}).items())
    elif isinstance(spec, list):
        if not all(isinstance(s, dict) for s in spec):
            raise GridError(f"{where}: a list 'env_kwargs' must hold mappings, got {spec!r}")
        named = [(_describe(s), dict(s)) for s in spec]
    else:
        named = [(_describe(s), s) for s in _product(f"{where} env_kwargs", spec)]
    if overrides is not None and not isinstance(overrides, dict):
        raise GridError(f"{where}: 'env_overrides' must be a mapping, got {overrides!r}")
    allowed = constructor_arguments(cls)
    out = []
    for name, kwargs in named:
        kwargs = {**kwargs, **(overrides or {})}
        unknown = sorted(set(kwargs) - set(allowed))
        if unknown:
            raise GridError(
                f"{where}: {env_id} has no argument(s) {unknown}; allowed: {sorted(allowed)}"
            )
        out.append((name, kwargs))
    return out


def _describe(kwargs: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in kwargs.items()) or "default arguments"


def _policies(where: str, env_id: str, spec: Any) -> list[str]:
    from cir_gym.scoring.policies import PolicyError, check_policy, policy_names

    if spec in (None, "all"):
        return policy_names(env_id)
    names = [spec] if isinstance(spec, str) else list(spec)
    for p in names:
        if not isinstance(p, str):
            raise GridError(f"{where}: a policy is a name, got {p!r}")
        if _is_factory(p):
            continue
        try:
            check_policy(env_id, p)
        except PolicyError as exc:
            raise GridError(
                f"{where}: {exc}, or 'module:callable' / 'file.py:callable'"
            ) from None
    return names


def _is_factory(policy: str) -> bool:
    """A user's ``module:callable`` / ``file.py:callable``, not a policy name (a controller,
    ``tuned:``, ``agent:`` or ``plugin:``)."""
    from cir_gym.scoring.policies import is_policy_name

    return not is_policy_name(policy)


def _gain_sets(where: str, env_id: str, policy: str, spec: Any) -> list[dict[str, Any]]:
    from cir_gym import baselines

    if not isinstance(spec, dict):
        raise GridError(f"{where}: 'gains' must map a controller to its gain axes, got {spec!r}")
    axes = spec.get(policy)
    sets = _product(f"{where} gains of {policy}", axes)
    if axes and policy in baselines.CONTROLLERS:
        fields = [
            f.name for f in dataclasses.fields(baselines.controller_class(policy, env_id).Gains)
        ]
        unknown = sorted(set(axes) - set(fields))
        if unknown:
            raise GridError(f"{where}: {policy} has no gain(s) {unknown}; gains: {fields}")
    elif axes and not _is_factory(policy):
        raise GridError(f"{where}: gains are given for {policy!r}, which takes none")
    return sets


def _positive_int(where: str, name: str, value: Any, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise GridError(f"{where}: '{name}' must be an integer >= {minimum}, got {value!r}")
    return value


EVALUATE_KEYS = (
    "envs",
    "policies",
    "seed",
    "episodes",
    "episodes_per_task",
    "env_kwargs",
    "env_overrides",
    "gains",
)
TRAIN_KEYS = (
    "envs",
    "algos",
    "residual",
    "seeds",
    "timesteps",
    "hyperparams",
    "hyperparams_path",
    "n_envs",
    "env_kwargs",
    "env_overrides",
    "evaluate",
)


def expand(grid: dict[str, Any]) -> list[dict[str, Any]]:
    """Every task of ``grid``: a list of plain parameter mappings, each with its ``task_id``.

    Raises:
        GridError: unknown keys, environments, policies, arguments or gains; bad counts;
            two training tasks that would write the same run directory.
    """
    from cir_gym.scoring.policies import has_tuned_gains, trained_for

    _check_keys("grid", grid, ("name", "evaluate", "train"))
    tasks: list[dict[str, Any]] = []
    for n, block in enumerate(_blocks(grid, "evaluate")):
        where = f"evaluate[{n}]"
        _check_keys(where, block, EVALUATE_KEYS)
        seed = block.get("seed", 1000)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise GridError(f"{where}: 'seed' must be an integer >= 0, got {seed!r}")
        episodes = _positive_int(where, "episodes", block.get("episodes", 10))
        per_task = _positive_int(where, "episodes_per_task", block.get("episodes_per_task", 1))
        for env_id in _env_ids(where, block):
            variants = _variants(where, env_id, block.get("env_kwargs"), block.get("env_overrides"))
            every = block.get("policies") in (None, "all")
            for policy in _policies(where, env_id, block.get("policies")):
                for gains in _gain_sets(where, env_id, policy, block.get("gains") or {}):
                    for variant, kwargs in variants:
                        if every and not trained_for(env_id, policy, kwargs):
                            continue  # "all": an agent only on its own task, as the leaderboard
                        if not has_tuned_gains(env_id, policy, kwargs):
                            if every:
                                continue  # "all": a tuned law where it was tuned, as above
                            raise GridError(
                                f"{where}: {policy} has no gains tuned for {env_id} with "
                                f"{_describe(kwargs)} (cir_gym/scoring/tuned_gains/); name "
                                f"{policy.removeprefix('tuned:')} at its course gains instead"
                            )
                        for first in range(seed, seed + episodes, per_task):
                            tasks.append(
                                {
                                    "kind": "evaluate",
                                    "env_id": env_id,
                                    "variant": variant,
                                    "policy": policy,
                                    "env_kwargs": kwargs,
                                    "gains": gains,
                                    "seed": first,
                                    "episodes": min(per_task, seed + episodes - first),
                                }
                            )
    for n, block in enumerate(_blocks(grid, "train")):
        tasks += _train_tasks(f"train[{n}]", block)
    names = [(t["env_id"], t["run_name"]) for t in tasks if t["kind"] == "train"]
    clash = sorted({x for x in names if names.count(x) > 1})
    if clash:
        raise GridError(
            f"training tasks would share run directories {clash}: give the "
            "hyperparameter sets distinct names"
        )
    for t in tasks:
        t["task_id"] = task_id(t)
    return tasks


def _train_tasks(where: str, block: dict[str, Any]) -> list[dict[str, Any]]:
    from cir_gym import baselines

    _check_keys(where, block, TRAIN_KEYS)
    algos = block.get("algos", ["ppo"])
    algos = [algos] if isinstance(algos, str) else list(algos)
    for a in algos:
        if a not in ALGORITHMS:
            raise GridError(f"{where}: unknown algorithm {a!r}; valid: {', '.join(ALGORITHMS)}")
    residuals = block.get("residual", [None])
    residuals = [residuals] if residuals is None or isinstance(residuals, str) else residuals
    seeds = block.get("seeds", [0])
    if isinstance(seeds, int) and not isinstance(seeds, bool):
        seeds = list(range(_positive_int(where, "seeds", seeds)))
    if not isinstance(seeds, list) or not all(isinstance(s, int) and s >= 0 for s in seeds):
        raise GridError(f"{where}: 'seeds' must be a count or a list of integers >= 0")
    timesteps = block.get("timesteps")
    if timesteps is not None:
        _positive_int(where, "timesteps", timesteps)
    n_envs = block.get("n_envs")
    if n_envs is not None:
        _positive_int(where, "n_envs", n_envs)
    hp_sets = block.get("hyperparams") or [{}]
    if not isinstance(hp_sets, list) or not all(isinstance(h, dict) for h in hp_sets):
        raise GridError(
            f"{where}: 'hyperparams' must be a list of mappings "
            "({name: ..., <hyperparameter>: value})"
        )
    ev = block.get("evaluate") or {}
    _check_keys(f"{where} evaluate", ev, ("episodes", "seed"))
    episodes = _positive_int(where, "evaluate.episodes", ev.get("episodes", 5), minimum=0)
    path = block.get("hyperparams_path")
    if path is not None and not Path(path).is_file():
        raise GridError(f"{where}: hyperparams_path {path} does not exist")
    out = []
    for env_id in _env_ids(where, block):
        variants = _variants(where, env_id, block.get("env_kwargs"), block.get("env_overrides"))
        for algo, residual, hp, (variant, kwargs), seed in itertools.product(
            algos, residuals, hp_sets, variants, seeds
        ):
            if residual is not None and residual not in baselines.available(env_id):
                raise GridError(
                    f"{where}: controller {residual!r} does not apply to {env_id}; "
                    f"available: {baselines.available(env_id)}"
                )
            hp = dict(hp)
            hp_name = str(hp.pop("name", "")) if hp else ""
            base = f"residual_{algo}_{residual}" if residual else algo
            label = f"{base}_{hp_name}" if hp_name else base
            if len(variants) > 1:
                label += f"_{task_id({'v': variant})[:6]}"
            out.append(
                {
                    "kind": "train",
                    "env_id": env_id,
                    "variant": variant,
                    "algo": algo,
                    "residual": residual,
                    "hp_set": hp_name,
                    "hyperparams": hp,
                    "hyperparams_path": str(Path(path).resolve()) if path else None,
                    "timesteps": timesteps,
                    "n_envs": n_envs,
                    "env_kwargs": kwargs,
                    "train_seed": seed,
                    "run_name": f"{label}/seed_{seed}",
                    "policy": f"train:{label}",
                    "eval_episodes": episodes,
                    "seed": int(ev.get("seed", 1000)),
                }
            )
    return out


# ---------------------------------------------------------------------- one task
def _factory(spec: str) -> Callable[..., Any]:
    """``module:callable`` or ``path/file.py:callable`` → the callable."""
    target, _, attr = spec.rpartition(":")
    if target.endswith(".py"):
        path = Path(target).resolve()
        name = f"_cir_gym_sweep_{hashlib.sha256(str(path).encode()).hexdigest()[:12]}"
        module = sys.modules.get(name)
        if module is None:
            loader = importlib.util.spec_from_file_location(name, path)
            if loader is None or loader.loader is None:
                raise ImportError(f"cannot load policy factory file {path}")
            module = importlib.util.module_from_spec(loader)
            loader.loader.exec_module(module)
            sys.modules[name] = module
    else:
        module = importlib.import_module(target)
    return getattr(module, attr)


def _policy(task: dict[str, Any]) -> Any:
    from cir_gym.scoring.policies import make_policy

    if _is_factory(task["policy"]):
        return _factory(task["policy"])(
            task["env_id"], dict(task["env_kwargs"]), dict(task["gains"])
        )
    return make_policy(task["env_id"], task["policy"], task["env_kwargs"], task["gains"])


def _one_thread() -> None:
    if "torch" in sys.modules:  # an agent's network: one thread per worker process
        sys.modules["torch"].set_num_threads(1)


def _base_row(task: dict[str, Any]) -> dict[str, Any]:
    row = {k: task.get(k) for k in PARAMS}
    row.update({f"env.{k}": v for k, v in task["env_kwargs"].items()})
    row.update({f"gain.{k}": v for k, v in (task.get("gains") or {}).items()})
    row.update({f"hp.{k}": v for k, v in (task.get("hyperparams") or {}).items()})
    return row


def _episode_rows(task: dict[str, Any], result: Any) -> list[dict[str, Any]]:
    rows = []
    for ep in result.episodes:
        row = _base_row(task)
        row.update(
            {
                "episode_seed": ep.seed,
                "return": ep.episode_return,
                "length": ep.length,
                "success": ep.success,
                "diverged": ep.diverged,
                "terminated": ep.terminated,
            }
        )
        row.update({f"metric.{k}": float(v) for k, v in ep.metrics.items()})
        rows.append(row)
    return rows


def _evaluate_rows(task: dict[str, Any], policy: Any, episodes: int) -> list[dict[str, Any]]:
    """``episodes`` episodes of ``policy`` from the task's seed, by the one evaluator."""
    from cir_gym.evaluation import evaluate

    _one_thread()
    result = evaluate(
        policy,
        task["env_id"],
        episodes,
        task["seed"],
        policy_name=task["policy"],
        **task["env_kwargs"],
    )
    return _episode_rows(task, result)


def _evaluate_task(task: dict[str, Any]) -> list[dict[str, Any]]:
    return _evaluate_rows(task, _policy(task), task["episodes"])


def _hyperparams_file(task: dict[str, Any], directory: Path) -> Path | None:
    """A copy of the algorithm's hyperparameter file (the shipped one or the grid's
    ``hyperparams_path``) with the task's set written into every section that
    :func:`agents.hyperparameters.load_hyperparams` merges for the environment (its entry,
    ``training`` and, for a residual run, ``residual``), so the set wins whatever the file
    says; the file itself when the set is empty (None: the shipped file)."""
    import yaml

    from cir_gym.agents.hyperparameters import HYPERPARAMS_DIR, _read_yaml

    hp = task["hyperparams"]
    if not hp:
        return task["hyperparams_path"]
    source = Path(task["hyperparams_path"] or HYPERPARAMS_DIR / f"{task['algo']}.yml")
    data = _read_yaml(source)  # the project's loader (1e6 is a float), merge keys resolved
    key = task["env_id"]
    data[key] = {**(data.get(key) or {}), **hp}
    for name in ("training", "residual") if task["residual"] else ("training",):
        section = data.get(name) or {}
        section[key] = {**(section.get(key) or {}), **hp}
        data[name] = section
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / f"{task['task_id']}_{task['algo']}.yml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _train_task(task: dict[str, Any], out: Path) -> tuple[list[dict[str, Any]], Path]:
    from cir_gym import agents
    from cir_gym.agents import env_dir_name
    from cir_gym.agents.train import train

    runs = out / "runs"
    run_dir = runs / env_dir_name(task["env_id"]) / task["run_name"]
    resume = (run_dir / "config.yml").is_file() and any(
        (run_dir / "checkpoints").glob("model_*_steps.zip")
    )
    if run_dir.exists() and not resume:  # an earlier attempt died before its first checkpoint
        shutil.rmtree(run_dir)
    hp_path = _hyperparams_file(task, out / "hyperparams")
    run_dir = train(
        task["env_id"],
        task["algo"],
        timesteps=task["timesteps"],
        seed=task["train_seed"],
        residual=task["residual"],
        resume=resume,
        out=runs,
        name=task["run_name"],
        env_kwargs=task["env_kwargs"],
        n_envs=task["n_envs"],
        hyperparams_path=hp_path,
        progress_bar=False,
        verbose=0,
    )
    rows = []
    if task["eval_episodes"] > 0:
        policy = agents.load(task["env_id"], task["policy"], path=run_dir)
        rows = _evaluate_rows(task, policy, task["eval_episodes"])
    else:
        rows = [_base_row(task)]
    rel = run_dir.relative_to(out).as_posix()
    for r in rows:
        r["run_dir"] = rel
    return rows, run_dir


def _archive(run_dir: Path) -> bytes:
    """The run directory (without checkpoints/ and tb/) as a tar.gz, for a driver elsewhere."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as tar:
        for f in sorted(run_dir.rglob("*")):
            rel = f.relative_to(run_dir)
            if f.is_file() and rel.parts[0] not in ("checkpoints", "tb"):
                tar.add(f, arcname=rel.as_posix())
    return buffer.getvalue()


def unpack_run(record: dict[str, Any], out: Path) -> Path | None:
    """Unpack the run directory that a training task on another host returned (``archive``,
    removed from ``record``) to ``out/<its run_dir>``, unless that directory exists (a shared
    filesystem, or this host ran it); return the directory, or None without an archive."""
    archive = record.pop("archive", None)
    if archive is None:
        return None
    run_dir = out / record["rows"][0]["run_dir"]
    if not run_dir.exists():
        with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
            tar.extractall(run_dir, filter="data")  # no absolute paths, links or devices
    return run_dir


def run_task(task: dict[str, Any], out: str, driver_host: str = "") -> dict[str, Any]:
    """Run one task in this process and return its record (raises on failure, for retries).

    Args:
        task: one entry of :func:`expand`.
        out: the sweep's output directory (training runs go to ``<out>/runs``).
        driver_host: the driver's host name; on another host a training task also returns its
            run directory as a tar.gz, which the driver unpacks (no shared filesystem needed).

    Returns:
        ``{"task_id", "status": "ok", "rows", "seconds", "worker"[, "archive"]}``.
    """
    t0 = time.perf_counter()
    record: dict[str, Any] = {"task_id": task["task_id"], "status": "ok"}
    if task["kind"] == "evaluate":
        record["rows"] = _evaluate_task(task)
    elif task["kind"] == "train":
        rows, run_dir = _train_task(task, Path(out))
        record["rows"] = rows
        if driver_host and driver_host != socket.gethostname():
            record["archive"] = _archive(run_dir)
    else:
        raise ValueError(f"unknown task kind {task['kind']!r}")
    record["seconds"] = time.perf_counter() - t0
    record["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return record


# ---------------------------------------------------------------------- executors
def _failed(task: dict[str, Any], error: str, detail: str, attempts: int) -> dict[str, Any]:
    return {
        "task_id": task["task_id"],
        "status": "failed",
        "error": error,
        "traceback": detail,
        "attempts": attempts,
        "rows": [],
    }


def _run_local(
    tasks: list[dict[str, Any]],
    out: Path,
    workers: int,
    retries: int,
    done: Callable[[dict[str, Any]], None],
) -> None:
    """Tasks on ``workers`` single-process executors (spawned): a dead process is charged to
    the one task it was running, which is retried like a task that raised."""
    spawn = multiprocessing.get_context("spawn")
    slots: list[ProcessPoolExecutor | None] = [None] * workers
    busy: dict[Future, tuple[int, dict[str, Any]]] = {}
    queue = deque(tasks)
    attempts: dict[str, int] = {}
    saved = {k: os.environ.get(k) for k in ONE_THREAD}
    os.environ.update({k: "1" for k in ONE_THREAD})  # inherited by the spawned workers
    try:
        while queue or busy:
            used = {slot for slot, _ in busy.values()}
            for slot in range(workers):
                if queue and slot not in used:
                    if slots[slot] is None:
                        slots[slot] = ProcessPoolExecutor(1, mp_context=spawn)
                    task = queue.popleft()
                    attempts[task["task_id"]] = attempts.get(task["task_id"], 0) + 1
                    busy[slots[slot].submit(run_task, task, str(out))] = (slot, task)
            finished, _ = wait(busy, return_when=FIRST_COMPLETED)
            for fut in finished:
                slot, task = busy.pop(fut)
                try:
                    record = fut.result()
                except BrokenProcessPool as exc:  # the worker died (killed, segfault, OOM)
                    slots[slot].shutdown(wait=False, cancel_futures=True)
                    slots[slot] = None
                    error, detail = f"worker process died: {exc}", ""
                except Exception as exc:  # the task raised (the worker's traceback is kept)
                    error = f"{type(exc).__name__}: {exc}"
                    detail = "".join(traceback.format_exception(exc))
                else:
                    record["attempts"] = attempts[task["task_id"]]
                    done(record)
                    continue
                if attempts[task["task_id"]] <= retries:
                    queue.appendleft(task)
                else:
                    done(_failed(task, error, detail, attempts[task["task_id"]]))
    finally:
        for ex in slots:
            if ex is not None:
                ex.shutdown(wait=False, cancel_futures=True)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _run_ray(
    tasks: list[dict[str, Any]],
    out: Path,
    address: str,
    workers: int | None,
    retries: int,
    done: Callable[[dict[str, Any]], None],
) -> None:
    """Tasks as Ray tasks (one CPU each): Ray schedules them and retries a task whose worker
    died (``max_retries``) or that raised (``retry_exceptions``)."""
    try:
        import ray
    except ImportError as exc:
        raise ImportError("--ray needs Ray: pip install 'cir-gym[sweep]'") from exc
    started = False
    if not ray.is_initialized():
        if address == "local":
            # a loaded machine may need longer than Ray's default to register the raylet
            os.environ.setdefault("RAY_raylet_start_wait_time_s", "120")
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
        else:
            try:
                ray.init(address=address, log_to_driver=False)
            except ConnectionError as exc:  # no cluster there ("auto": none on this machine)
                raise RayUnavailable(
                    f"--ray {address}: no Ray cluster found ({str(exc).split('.')[0]}); start "
                    "one with `ray start --head` (then --ray auto), or pass --ray local to "
                    "start one for this sweep; on one machine the local pool (no --ray) is as "
                    "fast (docs/sweeps.md)"
                ) from None
        started = True
    try:
        remote = ray.remote(num_cpus=1, max_retries=retries, retry_exceptions=True)(run_task)
        host = socket.gethostname()
        refs = {remote.remote(t, str(out), host): t for t in tasks}
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            task = refs[ready[0]]
            try:
                record = {**ray.get(ready[0]), "attempts": None}
            except Exception as exc:  # RayTaskError (it raised), WorkerCrashedError, ...
                cause = getattr(exc, "cause", None) or exc
                error = f"{type(cause).__name__}: {cause}".split("\n")[0]
                record = _failed(task, error, str(exc), retries + 1)
            done(record)
    finally:
        if started:
            ray.shutdown()


# ---------------------------------------------------------------------- results
def _write_json(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` to ``path`` atomically (a temporary file, then a rename)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(data, default=_json_default))
    os.replace(tmp, path)


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    return str(obj)


def _cell(value: Any) -> Any:
    """A table cell: bool/int/float/str/None; anything else as JSON text."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if hasattr(value, "item") and getattr(value, "ndim", 1) == 0:
        return value.item()
    return json.dumps(value, default=_json_default)


def _columns(rows: list[dict[str, Any]]) -> dict[str, list[Any]]:
    """Rows → columns of one type each (bool, int, float or str; None where missing)."""
    names = list(dict.fromkeys(k for r in rows for k in r))
    order = [c for c in LEADING if c in names] + sorted(c for c in names if c not in LEADING)
    cols = {}
    for c in order:
        values = [_cell(r.get(c)) for r in rows]
        present = [v for v in values if v is not None]
        if present and all(isinstance(v, bool) for v in present):
            pass
        elif present and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in present
        ):
            if any(isinstance(v, float) for v in present):
                values = [None if v is None else float(v) for v in values]
        else:
            values = [None if v is None else str(v) for v in values]
        cols[c] = values
    return cols


def write_table(rows: list[dict[str, Any]], out: Path, fmt: str = "auto") -> Path:
    """``out/results.parquet`` (pyarrow) or ``out/results.csv``; ``fmt``: auto/parquet/csv."""
    cols = _columns(rows)
    if fmt == "auto":
        fmt = "parquet" if importlib.util.find_spec("pyarrow") else "csv"
    for stale in out.glob(f"{TABLE_STEM}.*"):
        stale.unlink()
    if fmt == "parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        path = out / f"{TABLE_STEM}.parquet"
        pq.write_table(pa.table(cols), path)
        return path
    if fmt != "csv":
        raise ValueError(f"table format must be auto, parquet or csv, got {fmt!r}")
    path = out / f"{TABLE_STEM}.csv"
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(list(cols))
        for i in range(len(rows)):
            w.writerow(["" if v[i] is None else v[i] for v in cols.values()])
    return path


def _parse_csv_cell(text: str) -> Any:
    if text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def read_table(directory: str | Path) -> list[dict[str, Any]]:
    """The rows of a sweep's table (``results.parquet`` or ``results.csv`` in ``directory``)."""
    directory = Path(directory)
    parquet, plain = directory / f"{TABLE_STEM}.parquet", directory / f"{TABLE_STEM}.csv"
    if parquet.is_file():
        import pyarrow.parquet as pq

        return pq.read_table(parquet).to_pylist()
    if plain.is_file():
        with plain.open(newline="") as f:
            return [{k: _parse_csv_cell(v) for k, v in r.items()} for r in csv.DictReader(f)]
    raise FileNotFoundError(
        f"{directory} holds no sweep table ({parquet.name} or {plain.name});"
        " run `cir-gym sweep GRID --out DIR` first"
    )


@dataclasses.dataclass
class SweepSummary:
    """What :func:`run_sweep` did: task counts, wall time (s), the table's path."""

    tasks: int
    skipped: int
    ran: int
    failed: int
    seconds: float
    table: Path

    @property
    def tasks_per_s(self) -> float:
        return self.ran / self.seconds if self.seconds > 0 else float("nan")


def _progress(total: int, initial: int) -> Any:
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm comes with the train and plots extras
        return None
    return tqdm(total=total, initial=initial, desc="sweep", unit="task", file=sys.stderr)


def run_sweep(
    grid: dict[str, Any] | str | Path,
    out: str | Path,
    *,
    workers: int | None = None,
    ray: str | None = None,
    retries: int = 2,
    fmt: str = "auto",
    progress: bool = True,
) -> SweepSummary:
    """Run every unfinished task of ``grid`` and write the merged table into ``out``.

    Args:
        grid: a grid mapping or the path of its YAML file.
        out: the output directory (created; task files, runs and the table go there).
        workers: processes of the local pool (default: one per core); with ``ray="local"``
            the CPUs of the Ray instance started here.
        ray: None (local pool), ``"local"`` (start a Ray instance here), ``"auto"`` or a
            cluster address (``ray.init(address=...)``); an already initialised Ray is used.
        retries: attempts after the first before a task is recorded as failed.
        fmt: table format: "auto" (Parquet with pyarrow, else CSV), "parquet" or "csv".

    Returns:
        A :class:`SweepSummary`.
    """
    if isinstance(grid, (str, Path)):
        grid = load_grid(grid)
    if retries < 0:
        raise ValueError(f"retries must be >= 0, got {retries}")
    tasks = expand(grid)
    out = Path(out)
    task_dir = out / "tasks"
    task_dir.mkdir(parents=True, exist_ok=True)

    def finished(t: dict[str, Any]) -> bool:
        path = task_dir / f"{t['task_id']}.json"
        return path.is_file() and json.loads(path.read_text()).get("status") == "ok"

    todo = [t for t in tasks if not finished(t)]
    by_id = {t["task_id"]: t for t in tasks}
    bar = _progress(len(tasks), len(tasks) - len(todo)) if progress else None
    failures = 0

    def done(record: dict[str, Any]) -> None:
        nonlocal failures
        task = by_id[record["task_id"]]
        unpack_run(record, out)
        failures += record["status"] != "ok"
        _write_json(task_dir / f"{record['task_id']}.json", {**record, "task": task})
        if bar is not None:
            bar.set_postfix_str(
                f"{task['env_id'].split('/')[-1]} {task['policy']} {record['status']}"
            )
            bar.update(1)

    t0 = time.perf_counter()
    try:
        if todo and ray is not None:
            _run_ray(todo, out.resolve(), ray, workers, retries, done)
        elif todo:
            _run_local(
                todo,
                out.resolve(),
                max(1, min(workers or os.cpu_count() or 1, len(todo))),
                retries,
                done,
            )
    finally:
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - t0
    rows = []
    for t in tasks:
        path = task_dir / f"{t['task_id']}.json"
        if not path.is_file():
            continue
        record = json.loads(path.read_text())
        if record["status"] == "ok":
            rows += [{**r, "status": "ok", "error": None} for r in record["rows"]]
        else:
            rows.append({**_base_row(t), "status": "failed", "error": record["error"]})
    table = write_table(rows, out, fmt)
    summary = SweepSummary(len(tasks), len(tasks) - len(todo), len(todo), failures, seconds, table)
    (out / "sweep.json").write_text(
        json.dumps(
            {
                **dataclasses.asdict(summary),
                "table": table.name,
                "workers": workers,
                "ray": ray,
                "retries": retries,
            },
            indent=2,
        )
        + "\n"
    )
    return summary
