"""A normalized score on a leaderboard variant's primary metric: 0 = hold still, 1 = the
variant's first-ranked controller.

For a policy whose primary metric has mean m over the variant's episodes, with m_hold the mean
of the hold-still policy (:func:`hold_still_policy`, the same seeds) and m_best the mean of the
first-ranked controller (:func:`best_controller`), the score is :func:`normalized_score` of m
between them (:mod:`cir_gym.score_scale`: linear, or a log scale where the anchors are a decade
or more apart; 0 at m_hold, 1 at m_best, not clipped). The leaderboard measures both anchors on
its own seeds (:func:`variant_anchors`) and writes them to ``<out>/normalized.json``.

The best controller is the best row of the variant's table (its rank: success rate first, then
the mean) that is not a trained agent (``agent:``) nor the hold-still policy: a course
controller at course or tuned gains, a plugin policy, and a course controller at another
interface of the task — an agent-ready variant's (``impedance_insertion
[PegInHoleImpedance-v0]``, :mod:`cir_gym.baselines.setpoint`). Those are the course's
strategies expressed as setpoint motion of an impedance loop, not learned, and the interfaces
share the variant's seeds, metrics and success, so they may anchor 1: the score then measures
an agent against the best the course does on the task, whatever the interface. The 0 is the
task's own hold-still policy (the torque interface's PD + gravity); the agent-ready interface's
(a zero setpoint increment) holds the same pose.

"Hold still" is the policy that commands no motion on the variant's interface
(:data:`HOLD_STILL`, keyed by ``TaskContext.action_kind``): a zero action where the action is a
motion increment or a velocity (joint velocities, a camera twist, a Cartesian or impedance
setpoint increment); on a torque interface, where a zero action lets the arm fall, the course's
PD + gravity regulation to the posture of the first observation (``control-laws.md`` §5,
τ = ĝ(q) + K_P (q₀ − q) − K_D q̇ with the task's nominal model and tool; ω = 10 rad/s, ζ = 1,
scaled by diag B̂(q₀)).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from cir_gym.context import TaskContext
from cir_gym.evaluation import EvaluationResult
from cir_gym.impedance import tool_robot
from cir_gym.score_scale import LOG_DECADES, LOG_FLOOR, Anchors, normalized_score, uses_log_scale

__all__ = [
    "HOLD_STILL",
    "LOG_DECADES",
    "LOG_FLOOR",
    "Anchors",
    "HoldStill",
    "NormalizedScore",
    "best_controller",
    "episode_scores",
    "hold_still_policy",
    "is_agent",
    "normalized_score",
    "normalized_scores",
    "uses_log_scale",
    "variant_anchors",
]

#: action kind → what the hold-still policy commands on it
HOLD_STILL: dict[str, str] = {
    "joint_torque": "PD + gravity to the first observed posture (the arm would fall at τ = 0)",
    "motor_torque": "PD on the motor positions to their first observed values + ĝ(q) of the link "
    "positions (the springs' static deflection holds)",
    "joint_velocity": "zero joint velocities",
    "twist": "a zero camera twist",
    "cartesian_increment": "a zero setpoint increment",
    "impedance_setpoint_increment": "a zero setpoint increment (the impedance loop holds)",
}
_TORQUE_KINDS = ("joint_torque", "motor_torque")
POSTURE_OMEGA = 10.0  # rad/s: the hold-still PD on a torque interface
POSTURE_ZETA = 1.0


class HoldStill:
    """The hold-still policy of one interface (module docstring), with SB3's ``predict``.

    Its state is the posture q₀ (or motor positions θ₀) of the episode's first observation on a
    torque interface, None elsewhere. Use :func:`hold_still_policy` to build it.
    """

    name = "hold_still"
    batches_exactly = True

    def __init__(self, context: TaskContext, action_shape: tuple[int, ...]) -> None:
        if context.action_kind not in HOLD_STILL:
            raise ValueError(
                f"no hold-still policy for action kind {context.action_kind!r}; known: "
                f"{sorted(HOLD_STILL)}"
            )
        self.kind = context.action_kind
        self.action_shape = tuple(action_shape)
        self.scale = np.asarray(context.action_scale, dtype=float)
        self.robot = tool_robot(context) if self.kind in _TORQUE_KINDS else None

    def _torque(self, obs: dict[str, np.ndarray], q0: np.ndarray) -> np.ndarray:
        assert self.robot is not None
        q = np.asarray(obs["q"], dtype=float)
        if self.kind == "motor_torque":  # PD on the motor side, gravity of the links
            x, xd = np.asarray(obs["q_motor"], float), np.asarray(obs["qd_motor"], float)
        else:
            x, xd = q, np.asarray(obs["qd"], dtype=float)
        b = np.diag(self.robot.inertia(q0))
        tau = (
            self.robot.gravity(q)
            + POSTURE_OMEGA**2 * b * (q0 - x)
            - 2 * POSTURE_ZETA * POSTURE_OMEGA * b * xd
        )
        return np.clip(tau / self.scale, -1.0, 1.0)

    def _start(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        key = "q_motor" if self.kind == "motor_torque" else "q"
        return np.array(obs[key], dtype=float)

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """Zeros, or the PD + gravity torque (one observation, or a batch: leading axis)."""
        if self.robot is None:
            batch = _batch_size(observation, self.action_shape)
            shape = self.action_shape if batch is None else (batch, *self.action_shape)
            return np.zeros(shape, dtype=np.float32), state
        batch = _batch_size(observation, self.action_shape, key="q")
        rows = [observation] if batch is None else [
            {k: v[i] for k, v in observation.items()} for i in range(batch)
        ]
        starts = np.ones(len(rows), bool) if episode_start is None else np.atleast_1d(episode_start)
        q0s = [None] * len(rows) if state is None else list(np.atleast_2d(state))
        actions, new_state = [], []
        for row, start, q0 in zip(rows, starts, q0s, strict=True):
            q0 = self._start(row) if start or q0 is None else np.asarray(q0, float)
            actions.append(self._torque(row, q0))
            new_state.append(q0)
        if batch is None:
            return actions[0].astype(np.float32), new_state[0]
        return np.array(actions, dtype=np.float32), np.array(new_state)


def _batch_size(
    observation: Any, action_shape: tuple[int, ...], key: str | None = None
) -> int | None:
    """None for one observation, else the number of stacked observations (vector envs)."""
    if isinstance(observation, dict):
        key = key or next(iter(observation))
        x = np.asarray(observation[key])
        return None if x.ndim <= 1 else int(x.shape[0])
    x = np.asarray(observation)
    return None if x.ndim <= 1 else int(x.shape[0])


def hold_still_policy(env: Any) -> HoldStill:
    """The hold-still policy of ``env``'s interface (its ``controller_context().action_kind``)."""
    base = env.unwrapped
    return HoldStill(base.controller_context(), base.action_space.shape)


@dataclass(frozen=True)
class NormalizedScore:
    """One policy's normalized score on a metric, with its anchors.

    Attributes:
        policy_name: the result's policy.
        metric: the metric scored (the result's primary metric by default).
        score: the normalized score of the mean.
        value: the policy's mean m.
        hold, best: the anchors' means m_hold and m_best.
        best_policy: the policy whose mean is m_best.
        log_scale: whether the log formula was used.
    """

    policy_name: str
    metric: str
    score: float
    value: float
    hold: float
    best: float
    best_policy: str
    log_scale: bool


def _mean(result: EvaluationResult, metric: str) -> float:
    if metric not in result.summary:
        raise ValueError(
            f"{result.policy_name!r} on {result.env_id} has no metric {metric!r}; metrics: "
            f"{[s.name for s in result.specs]}"
        )
    return float(result.summary[metric]["mean"])


def is_agent(result: EvaluationResult) -> bool:
    """Whether a result is a trained agent's (the leaderboard's ``agent:`` names)."""
    return result.policy_name.startswith("agent:")


def best_controller(
    results: Iterable[EvaluationResult], metric: str | None = None
) -> EvaluationResult:
    """The controller (not an ``agent:`` and not the hold-still policy; at any interface of the
    task: the module docstring) ranked first on ``metric`` (default: the results' primary
    metric) as the leaderboard's tables rank (:func:`cir_gym.evaluation.rank`): the highest
    success rate, then the best mean in the metric's direction. The score's 1 is then the
    tables' best controller: a faster mean bought with failed episodes does not anchor it.

    Raises:
        ValueError: no controller result with a finite mean.
    """
    rows = [r for r in results if not is_agent(r) and r.policy_name != HoldStill.name]
    if not rows:
        raise ValueError("no controller result to anchor the score at 1")
    name = metric or rows[0].primary_metric
    _mean(rows[0], name)  # a clear error for an unknown metric
    finite = [r for r in rows if math.isfinite(_mean(r, name))]
    if not finite:
        raise ValueError(f"no controller has a finite mean of {name!r}")
    return min(finite, key=lambda r: r.ranked_on(name).rank_key())


def variant_anchors(
    results: Iterable[EvaluationResult],
    hold: EvaluationResult,
    best: EvaluationResult | None = None,
    metric: str | None = None,
    *,
    log: bool | None = None,
) -> Anchors:
    """The anchors of one leaderboard variant: the hold-still policy's mean (0) and the best
    controller's (1) on ``metric`` (default: ``hold``'s primary metric, the variant's own when
    the results are ``EvaluationResult.ranked_on`` it).

    Args:
        results: the variant's results (controllers and agents, same env and seeds).
        hold: the hold-still policy's result on the same seeds (score 0).
        best: the result scoring 1; None: :func:`best_controller` of ``results``.
        metric: the metric scored; None: ``hold``'s primary metric.
        log: the scale; None: :func:`uses_log_scale` of the anchors.

    Raises:
        ValueError: an unknown metric, no controller with a finite mean, anchors that are
            equal or not finite, or a hold-still mean better than the anchor's in the metric's
            direction (no scale: it would rank failing rows above 1; the message gives both).
    """
    rows = list(results)
    name = metric or hold.primary_metric
    anchor = best if best is not None else best_controller(rows, name)
    m_hold, m_best = _mean(hold, name), _mean(anchor, name)
    spec = hold.spec(name)
    hold_is_better = m_hold < m_best if spec.better == "lower" else m_hold > m_best
    if hold_is_better:
        raise ValueError(
            f"holding still ({m_hold:.3g}) is better on {name!r} ({spec.better} is better) than "
            f"the first-ranked controller {anchor.policy_name} ({m_best:.3g}): no scale"
        )
    unit = spec.unit
    if log is None:
        return Anchors.of(name, m_hold, m_best, anchor.policy_name, unit)
    return Anchors(name, m_hold, m_best, anchor.policy_name, log, unit)


def normalized_scores(
    results: Iterable[EvaluationResult],
    hold: EvaluationResult,
    best: EvaluationResult | None = None,
    metric: str | None = None,
    *,
    log: bool | None = None,
) -> dict[str, NormalizedScore]:
    """The normalized score of every result on one leaderboard variant (the arguments of
    :func:`variant_anchors`); the results may be on any interface of the anchors' task
    (:func:`cir_gym.scoring.policies.task_id`).

    Returns:
        policy name → :class:`NormalizedScore`.
    """
    from cir_gym.scoring.policies import task_id

    rows = list(results)
    anchors = variant_anchors(rows, hold, best, metric, log=log)
    out = {}
    for r in rows:
        if task_id(r.env_id) != task_id(hold.env_id):
            raise ValueError(
                f"{r.policy_name!r} is on {r.env_id}, another task than the anchors' "
                f"{hold.env_id}"
            )
        value = _mean(r, anchors.metric)
        out[r.policy_name] = NormalizedScore(
            r.policy_name,
            anchors.metric,
            anchors.score(value),
            value,
            anchors.hold,
            anchors.best,
            anchors.best_policy,
            anchors.log,
        )
    return out


def episode_scores(
    result: EvaluationResult,
    hold: EvaluationResult,
    best: EvaluationResult,
    metric: str | None = None,
    *,
    log: bool | None = None,
) -> np.ndarray:
    """Per-episode normalized scores (n_episodes,) of ``result``, for an IQM with a bootstrap
    interval: each episode's metric scored between the anchors' means (the scale of
    :func:`normalized_scores`). NaN metrics give NaN."""
    anchors = variant_anchors([best], hold, best, metric, log=log)
    return anchors.scores([ep.metrics.get(anchors.metric, np.nan) for ep in result.episodes])
