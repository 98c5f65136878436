"""One scorer for every policy: episodes on fixed seeds → per-episode and aggregated metrics.

A policy is anything with SB3's ``predict(observation, state, episode_start, deterministic)``
(a classical controller from ``baselines`` or a trained agent from ``agents``). Episode ``i``
is reset with seed ``seed + i``, so every policy meets the same references, initial states
and model errors. Metrics come from the environment's ``metric_specs`` and its
``info["episode_metrics"]`` at the last step; nothing else is computed here.

Batched evaluation: where ``cir_gym.envs.vector`` has a native batched env for the id and its
arguments (``VECTOR_ENVS``: JointTracking-v2 and ElasticJointTracking-v3 unless ``randomize``,
CartesianTracking-v1 with exact sensing, AdmittanceContact-v2, ...; see
``cir_gym.envs.vector.native_vector_env``) and the policy gives the same actions for a batch of
observations as for each one alone (:func:`batches_exactly`: the course controllers, whose
``predict`` runs one code for a row alone and for a batch, tested bit for bit in
``tests/test_batched_laws.py``), :func:`evaluate` runs up to ``MAX_BATCH`` episodes at once on
one ``mujoco.batch.Batch`` and one ``predict`` per step for all of them. Each copy is the single
env step for step, to the tolerance its tests state (``tests/test_vector.py``,
``tests/test_vector_cartesian.py``: observations equal, rewards and metrics to 1e-12 relative),
so every ``EpisodeResult`` is the sequential path's to that tolerance
(``tests/test_evaluation.py`` and those files compare them). Everything else — other ids,
unsupported arguments (each batched env's ``unsupported`` names them), ``record=True``, a given
``env``, trained agents (a torch network rounds a batch differently from one row, in the last
float32 bit) — runs one episode after the other, unless the caller asks for ``batched=True``
(:func:`batchable` says where it can): then a trained agent's episodes equal the sequential
ones to the tolerance its caller states, not bit for bit (the leaderboard does so for its agents,
``cir_gym.scoring.leaderboard.AGENT_BATCH_IDS``, tested in ``tests/test_batched_agents.py``).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from cir_gym.envs.base import make_env
from cir_gym.metrics import MetricSpec, aggregate

__all__ = [
    "MAX_BATCH",
    "EpisodeResult",
    "EvaluationResult",
    "Policy",
    "batchable",
    "batches_exactly",
    "check_env_interface",
    "evaluate",
    "interface_env_kwargs",
    "metric_specs",
    "rank",
    "variant_primary_metric",
]


#: most episodes run at once by the batched path (more are run in groups of this size)
MAX_BATCH = 128
#: MuJoCo threads of the batched path: 1, as the leaderboard already runs one worker per core
BATCH_THREADS = 1


class Policy(Protocol):
    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]: ...


def interface_env_kwargs(policy: Any, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """``env_kwargs`` with the action interface that ``policy``'s actions are defined on.

    A policy may carry ``interface_kwargs``: environment arguments without which its actions
    mean something else (a trained agent's recorded ``control``/``control_freq``: a PegInHole
    agent of the position interface outputs 6 pose increments, not 7 torques). They are added
    to the task's arguments wherever an environment is built for the policy (evaluation,
    videos). A task argument that contradicts them is an error, never silently replaced.

    Raises:
        ValueError: ``env_kwargs`` sets an interface argument to another value.
    """
    interface = dict(getattr(policy, "interface_kwargs", None) or {})
    clash = {
        k: (env_kwargs[k], v)
        for k, v in interface.items()
        if k in env_kwargs and env_kwargs[k] != v
    }
    if clash:
        text = ", ".join(f"{k}={a!r} (the policy acts on {k}={b!r})" for k, (a, b) in clash.items())
        raise ValueError(
            f"the environment arguments contradict the policy's action interface: {text}"
        )
    return {**env_kwargs, **interface}


_MISSING = object()


def _env_interface_value(env: gym.Env, key: str) -> Any:
    """The value of the interface argument ``key`` that ``env`` was built with: its control
    rate 1 / ``dt`` for ``control_freq``, else the env's attribute of that name (PegInHole's
    and AdmittanceContact's ``control``), else the argument given to ``gymnasium.make``
    (``env.spec.kwargs``); ``_MISSING`` if none says."""
    base = env.unwrapped
    if key == "control_freq" and getattr(base, "dt", None):
        return 1.0 / float(base.dt)
    value = getattr(base, key, _MISSING)
    if value is _MISSING and env.spec is not None:
        value = (env.spec.kwargs or {}).get(key, _MISSING)
    return value


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return bool(np.isclose(float(a), float(b), rtol=1e-9, atol=0.0))
    return bool(a == b)


def check_env_interface(policy: Any, env: gym.Env) -> None:
    """Refuse a ready ``env`` whose action interface is not ``policy``'s ``interface_kwargs``.

    :func:`interface_env_kwargs` builds an environment on the policy's interface; an env the
    caller built may be on another one. Its actions would then be scored at another rate or
    with another meaning, silently whenever the action shapes agree (a JointTracking agent
    trained at ``control_freq=100`` on the default 500 Hz env). ``control_freq`` is compared
    with the env's 1 / ``dt`` (to 1e-9, relative), other keys with the env's attribute or
    its ``gymnasium.make`` arguments.

    Raises:
        ValueError: naming each differing argument, the env's value and the policy's.
    """
    interface = dict(getattr(policy, "interface_kwargs", None) or {})
    clash = {}
    for key, needed in interface.items():
        has = _env_interface_value(env, key)
        if has is _MISSING or not _same(has, needed):
            clash[key] = (has, needed)
    if clash:
        name = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
        text = "; ".join(
            f"{k}: the env has "
            + ("no such argument" if has is _MISSING else f"{k}={has!r}")
            + f", the policy needs {k}={needed!r}"
            for k, (has, needed) in clash.items()
        )
        raise ValueError(
            f"the given {name} env is not on the policy's action interface ({text}); build "
            "it with the policy's interface_kwargs (interface_env_kwargs), or let evaluate "
            "make it"
        )


@dataclass
class EpisodeResult:
    """One episode: its seed, return, length, success, divergence, metrics, whether it ended
    by termination (rather than truncation at the time limit), and (optionally)
    the recorded trajectory ``trace`` (dict of arrays (T, ...): observations, actions, rewards,
    and the policy state when it has one)."""

    seed: int
    episode_return: float
    length: int
    success: bool
    diverged: bool
    metrics: dict[str, float]
    trace: dict[str, np.ndarray] | None = None
    terminated: bool = False


@dataclass
class EvaluationResult:
    """Results of :func:`evaluate`; ``summary`` aggregates every metric over the episodes."""

    env_id: str
    policy_name: str
    episodes: list[EpisodeResult]
    specs: tuple[MetricSpec, ...]
    primary_metric: str
    dt: float = 1.0
    summary: dict[str, dict[str, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for spec in self.specs:
            self.summary[spec.name] = aggregate(
                spec, np.array([ep.metrics.get(spec.name, np.nan) for ep in self.episodes])
            )
        returns = np.array([ep.episode_return for ep in self.episodes])
        self.summary["return"] = aggregate(MetricSpec("return", "", "higher", ""), returns)

    @property
    def success_rate(self) -> float:
        return float(np.mean([ep.success for ep in self.episodes]))

    @property
    def divergence_rate(self) -> float:
        return float(np.mean([ep.diverged for ep in self.episodes]))

    @property
    def returns(self) -> np.ndarray:
        return np.array([ep.episode_return for ep in self.episodes])

    def spec(self, name: str) -> MetricSpec:
        return next(s for s in self.specs if s.name == name)

    def ranked_on(self, metric: str) -> EvaluationResult:
        """This result with ``metric`` (one of ``specs``) as its primary metric, e.g. a
        leaderboard variant's own (:func:`variant_primary_metric`); the episodes are shared."""
        if metric not in {s.name for s in self.specs}:
            raise ValueError(
                f"{metric!r} is not a metric of {self.env_id}; metrics: "
                f"{[s.name for s in self.specs]}"
            )
        return EvaluationResult(
            self.env_id, self.policy_name, self.episodes, self.specs, metric, dt=self.dt
        )

    def rank_key(self) -> tuple[float, float]:
        """Sort key of :func:`rank`: the highest success rate first, then the best mean of the
        primary metric (in its own direction; NaN last)."""
        mean = self.summary[self.primary_metric]["mean"]
        if not np.isfinite(mean):
            return (-self.success_rate, float("inf"))
        return (
            -self.success_rate,
            -mean if self.spec(self.primary_metric).better == "higher" else mean,
        )


def rank(results: list[EvaluationResult]) -> list[EvaluationResult]:
    """``results`` best first: success rate, then the primary metric's mean (NaN last).

    Success comes first because an episode that ends early (at a joint limit, on an
    obstacle, at the following-error monitor) can still show a good value of a metric it
    stopped accumulating.
    """
    return sorted(results, key=EvaluationResult.rank_key)


def variant_primary_metric(env_cls: type, variant: str) -> str:
    """The metric a leaderboard variant of ``env_cls`` is ranked on: its entry in the class's
    ``leaderboard_primary_metrics`` (variant name → metric name, next to
    ``leaderboard_variants``), else the class's ``primary_metric``."""
    own = getattr(env_cls, "leaderboard_primary_metrics", {}) or {}
    return str(own.get(variant, env_cls.primary_metric))


def metric_specs(env: gym.Env) -> tuple[tuple[MetricSpec, ...], str]:
    """(metric specs, primary metric name) declared by an environment."""
    base = env.unwrapped
    return tuple(base.metric_specs), str(base.primary_metric)


def _check_action_shape(action: Any, env: gym.Env, policy_name: str) -> None:
    shape = env.action_space.shape
    if np.shape(action) != shape:
        raise ValueError(
            f"policy {policy_name!r} returned an action of shape {np.shape(action)}; "
            f"{env.spec.id if env.spec else 'the environment'} expects shape {shape}"
        )


def evaluate(
    policy: Policy,
    env_id: str,
    n_episodes: int = 10,
    seed: int = 0,
    *,
    record: bool = False,
    policy_name: str | None = None,
    deterministic: bool = True,
    env: gym.Env | None = None,
    batched: bool | None = None,
    **env_kwargs: Any,
) -> EvaluationResult:
    """Run ``n_episodes`` episodes of ``policy`` on ``env_id`` with seeds seed, seed+1, ….

    Args:
        policy: object with SB3's ``predict``.
        env_id: registered id (``cir_gym/<Name>-v<N>``).
        n_episodes: number of episodes (≥ 1).
        seed: seed of the first episode.
        record: keep each episode's trajectory in ``EpisodeResult.trace`` (for plots).
        policy_name: label for tables (default: the policy's ``name`` or class name).
        env: use this environment instead of making one (``env_kwargs`` must then be empty;
            it must be on the policy's ``interface_kwargs``: :func:`check_env_interface`).
        batched: None (default): the episodes run batched on ``cir_gym.envs.vector``'s native env
            when the id and ``env_kwargs`` have one and :func:`batches_exactly` holds for the
            policy (the same results as one at a time, faster), else one after the other.
            False: always one after the other. True: batched whenever the env allows it, for
            any policy whose ``predict`` takes stacked observations (a trained agent: its
            network rounds a batch differently, so results agree with the sequential ones to
            float rounding, not bit for bit); ValueError if the env does not allow it.
        **env_kwargs: environment arguments.

    Returns:
        An :class:`EvaluationResult`.
    """
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    name = policy_name or getattr(policy, "name", None) or type(policy).__name__
    if env is None:
        env_kwargs = interface_env_kwargs(policy, env_kwargs)
    vec_cls = _batched_env_class(env_id, env, record, env_kwargs, batched)
    if vec_cls is not None and (batched or batches_exactly(policy)):
        specs, primary = (
            tuple(vec_cls.env_class.metric_specs),
            str(vec_cls.env_class.primary_metric),
        )
        episodes, dt = _evaluate_batched(
            policy, vec_cls, n_episodes, seed, deterministic, name, env_kwargs
        )
        return EvaluationResult(env_id, name, episodes, specs, primary, dt=dt)
    own_env = env is None
    if env is None:
        env = make_env(env_id, **env_kwargs)  # no TimeLimit cuts a longer episode
    elif env_kwargs:
        raise ValueError("pass env_kwargs or an env, not both")
    else:
        check_env_interface(policy, env)
    specs, primary = metric_specs(env)
    dt = float(getattr(env.unwrapped, "dt", 1.0))  # s per step, for plots
    episodes: list[EpisodeResult] = []
    try:
        for i in range(n_episodes):
            obs, _ = env.reset(seed=seed + i)
            state = None
            start = np.ones(1, dtype=bool)
            total, length, done = 0.0, 0, False
            info: dict[str, Any] = {}
            trace: dict[str, list] | None = {} if record else None
            while not done:
                action, state = policy.predict(
                    obs, state=state, episode_start=start, deterministic=deterministic
                )
                start = np.zeros(1, dtype=bool)
                _check_action_shape(action, env, name)
                if trace is not None:
                    _append(trace, "obs", obs)
                    trace.setdefault("action", []).append(np.array(action, dtype=float))
                    if state is not None and np.size(state) > 0:
                        trace.setdefault("state", []).append(np.array(state, dtype=float).ravel())
                obs, reward, terminated, truncated, info = env.step(action)
                if trace is not None:
                    trace.setdefault("reward", []).append(float(reward))
                    for key in ("joint_error", "task_error"):
                        if key in info:
                            trace.setdefault(key, []).append(info[key])
                total += float(reward)
                length += 1
                done = terminated or truncated
            metrics = dict(info.get("episode_metrics", {}))
            episodes.append(
                EpisodeResult(
                    seed=seed + i,
                    episode_return=total,
                    length=length,
                    success=bool(info.get("is_success", False)),
                    diverged=bool(info.get("diverged", False)),
                    metrics=metrics,
                    trace=_stack(trace) if trace is not None else None,
                    terminated=bool(terminated),
                )
            )
    finally:
        if own_env:
            env.close()
    return EvaluationResult(env_id, name, episodes, specs, primary, dt=dt)


def batches_exactly(policy: Any) -> bool:
    """Whether ``policy.predict`` on stacked observations gives, row for row, the actions it
    gives for each observation alone (bit for bit), so batched episodes are the sequential ones.

    A policy says so with an attribute ``batches_exactly`` (bool). Without one: True for a
    ``baselines.Controller`` (a row-vectorised law runs the same code on a row alone and in a
    batch, the others ``control`` on each row with that row's state), False for anything else (a
    trained agent's torch network rounds a batch of rows differently from one row: actions
    differ by ~1e-7).
    """
    flag = getattr(policy, "batches_exactly", None)
    if flag is not None:
        return bool(flag)
    # a Controller exists only if the baselines are imported
    base = sys.modules.get("cir_gym.baselines.base")
    return base is not None and isinstance(policy, base.Controller)


def batchable(policy: Any, env_id: str, **env_kwargs: Any) -> bool:
    """Whether ``evaluate(policy, env_id, batched=True, **env_kwargs)`` can batch: a native
    batched env exists for ``env_id`` with ``env_kwargs`` and the policy's
    ``interface_kwargs`` (:func:`interface_env_kwargs`; e.g. a 100-Hz agent's
    ``control_freq``). Says nothing about how closely the policy batches
    (:func:`batches_exactly`)."""
    kwargs = interface_env_kwargs(policy, env_kwargs)
    return _batched_env_class(env_id, None, False, kwargs, None) is not None


def _batched_env_class(
    env_id: str, env: gym.Env | None, record: bool, env_kwargs: dict[str, Any], batched: bool | None
) -> type | None:
    """The native batched env class :func:`evaluate` may use, or None (see its ``batched``)."""
    if batched is False:
        return None
    from cir_gym.envs.vector import VECTOR_ENVS, native_vector_env

    reasons = []
    if env is not None:
        reasons.append("an env was given")
    if record:
        reasons.append("record=True keeps per-step traces")
    if env_kwargs.get("max_episode_steps", -1) != -1:
        reasons.append("a max_episode_steps below the episode's end")
    vec_cls = None if reasons else native_vector_env(env_id, env_kwargs)
    if vec_cls is None and not reasons:
        native = VECTOR_ENVS.get(env_id.split(":")[-1])
        reasons.append(
            f"the batched {env_id} cannot batch {native.unsupported(env_kwargs)}"
            if native is not None
            else f"cir_gym.envs.vector has no batched {env_id} (it has {sorted(VECTOR_ENVS)})"
        )
    if reasons and batched:
        raise ValueError(f"evaluate(batched=True) cannot batch: {'; '.join(reasons)}")
    return vec_cls


def _evaluate_batched(
    policy: Policy,
    vec_cls: type,
    n_episodes: int,
    seed: int,
    deterministic: bool,
    name: str,
    env_kwargs: dict[str, Any],
) -> tuple[list[EpisodeResult], float]:
    """Episodes seed … seed + n_episodes − 1 in groups of ``MAX_BATCH`` copies of ``vec_cls``.

    Copy i of a group is reset with its own seed and stepped until its first episode ends;
    what it plays after its autoreset is discarded (the group runs until every copy has ended
    once; the controllers' state of a restarted copy is reset by ``episode_start``). Returns
    and lengths are summed per copy in the sequential path's order, so they are equal.
    """
    kwargs = {k: v for k, v in env_kwargs.items() if k != "max_episode_steps"}
    episodes: list[EpisodeResult] = []
    dt = 1.0
    for first in range(0, n_episodes, MAX_BATCH):
        seeds = list(range(seed + first, seed + min(first + MAX_BATCH, n_episodes)))
        b = len(seeds)
        venv = vec_cls(num_envs=b, nthread=BATCH_THREADS, **kwargs)
        try:
            dt = float(venv.template.dt)
            shape = venv.action_space.shape
            obs, _ = venv.reset(seed=seeds)
            state = None
            start = np.ones(b, dtype=bool)
            total = np.zeros(b)
            length = np.zeros(b, dtype=np.int64)
            live = np.ones(b, dtype=bool)
            ended: list[EpisodeResult | None] = [None] * b
            while live.any():
                action, state = policy.predict(
                    obs, state=state, episode_start=start, deterministic=deterministic
                )
                if np.shape(action) != shape:
                    raise ValueError(
                        f"policy {name!r} returned actions of shape {np.shape(action)} for "
                        f"{b} stacked observations; the batched {vec_cls.env_id} expects {shape} "
                        "(evaluate(..., batched=False) runs one observation at a time)"
                    )
                obs, reward, terminated, truncated, infos = venv.step(action)
                total[live] += reward[live]
                length[live] += 1
                start = terminated | truncated
                for i in np.flatnonzero(start & live):
                    final = infos["final_info"]
                    ended[i] = EpisodeResult(
                        seed=seeds[i],
                        episode_return=float(total[i]),
                        length=int(length[i]),
                        success=bool(final["is_success"][i]),
                        diverged=bool(final["diverged"][i]),
                        metrics={  # without gymnasium's "_<name>" masks
                            k: float(v[i])
                            for k, v in final["episode_metrics"].items()
                            if not k.startswith("_")
                        },
                        terminated=bool(terminated[i]),
                    )
                live &= ~start
        finally:
            venv.close()
        episodes += [e for e in ended if e is not None]
    return episodes, dt


def _append(trace: dict[str, list], prefix: str, obs: Any) -> None:
    if isinstance(obs, dict):
        for k, v in obs.items():
            trace.setdefault(f"{prefix}/{k}", []).append(np.array(v, dtype=float))
    else:
        trace.setdefault(prefix, []).append(np.array(obs, dtype=float))


def _stack(trace: dict[str, list]) -> dict[str, np.ndarray]:
    return {k: np.asarray(v) for k, v in trace.items()}
