"""Agent-ready variants of the contact tasks: a policy at 10–50 Hz moves the setpoint of an
env-side Cartesian impedance loop with gravity compensation (chapter 6) that drives the task's
500-Hz torque interface.

Each variant owns an instance of the task (``control="torque"``, 500 Hz) and plays it: one
policy step moves the pose setpoint (and optionally the stiffness), then runs the impedance law
of :mod:`cir_gym.impedance` at every one of the task's control steps in the policy period.
Reset, seeds, physics, metrics and success are the task's own (``info["episode_metrics"]`` and
``info["is_success"]`` come unchanged from the task's last step); the reward is the variant's.
:mod:`cir_gym.envs.agent_ready_vector` batches both variants (N copies on the task's batched
env), with the same methods on (N, ...) arrays.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from cir_gym import trajectories as traj
from cir_gym.context import TaskContext
from cir_gym.envs.admittance_contact import AdmittanceContactEnv
from cir_gym.envs.admittance_scene import TIMESTEP
from cir_gym.envs.base import RobotEnv
from cir_gym.envs.peg_in_hole import PegInHoleEnv
from cir_gym.impedance import (
    CartesianImpedance,
    ImpedanceGains,
    critical_damping,
    exp_rotvec,
    log_rotation,
    pose_error,
    tool_robot,
)
from cir_gym.validation import InvalidArgument, check_flag, check_number

__all__ = [
    "IMPEDANCE_FREQ",
    "STIFFNESS_RANGE",
    "AdmittanceContactImpedanceEnv",
    "ImpedanceTaskEnv",
    "PegInHoleImpedanceEnv",
    "move_setpoint",
    "stiffness_from_action",
]

#: Hz: the rate of the impedance loop, the task's torque interface (its default control rate)
IMPEDANCE_FREQ = 500.0
#: Hz: the policy rates allowed (IMPEDANCE_FREQ / control_freq must be an integer)
POLICY_FREQ_RANGE = (10.0, 50.0)
#: variable impedance: (lowest, highest) translational (N/m) and rotational (N m/rad) stiffness
STIFFNESS_RANGE = ((100.0, 5000.0), (5.0, 250.0))
#: observation bound of the setpoint offset: m, rad (the offset is clamped far below)
_OFFSET_BOUND = np.r_[np.full(3, 1.0), np.full(3, np.pi)]
#: STIFFNESS_RANGE as (6,) arrays: K_p's lowest and highest values
_K_LOW = np.r_[np.full(3, STIFFNESS_RANGE[0][0]), np.full(3, STIFFNESS_RANGE[1][0])]
_K_HIGH = np.r_[np.full(3, STIFFNESS_RANGE[0][1]), np.full(3, STIFFNESS_RANGE[1][1])]


def move_setpoint(
    p_d: np.ndarray,
    R_d: np.ndarray,
    dx: np.ndarray,
    p: np.ndarray,
    R: np.ndarray,
    max_offset: float,
    max_angle: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The setpoints moved by dx = [δp; δφ] (..., 6) (m, rad, world frame): p_d + δp and
    exp(δφ) R_d, then clamped to ``max_offset`` (m) and ``max_angle`` (rad) from the current
    poses (p (..., 3), R (..., 3, 3)). One setpoint or N (leading shape (N,)).

    Returns:
        (p_d (..., 3), R_d (..., 3, 3)).
    """
    p_new = p_d + dx[..., :3]
    offset = p_new - p
    dist = np.linalg.norm(offset, axis=-1, keepdims=True)
    far = dist > max_offset
    with np.errstate(invalid="ignore", divide="ignore"):
        p_new = np.where(far, p + offset * (max_offset / np.where(far, dist, 1.0)), p_new)
    R_new = exp_rotvec(dx[..., 3:]) @ R_d
    phi = log_rotation(R_new @ np.swapaxes(R, -1, -2))
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    wide = angle > max_angle
    if np.any(wide):
        with np.errstate(invalid="ignore", divide="ignore"):
            clamped = exp_rotvec(phi * (max_angle / np.where(wide, angle, 1.0))) @ R
        R_new = np.where(wide[..., None], clamped, R_new)
    return p_new, R_new


def stiffness_from_action(a: np.ndarray) -> np.ndarray:
    """K_p (..., 6) of the stiffness actions a (..., 6) ∈ [−1, 1]: log scale over
    STIFFNESS_RANGE (−1: the lowest, 0: the geometric mean, 1: the highest)."""
    return _K_LOW * (_K_HIGH / _K_LOW) ** ((a + 1.0) / 2.0)


class ImpedanceTaskEnv(RobotEnv):
    """Shared plumbing of the agent-ready variants (module docstring); not registered itself.

    A subclass builds its task from ``task_arguments`` (the task's constructor arguments,
    kept so that a batched env builds the same task) and says what its reward's task term is
    (:meth:`_task_term`, per task control step, in [−1, 0]) and where the controlled point is
    (:meth:`_tcp_offset`). The policy step's arithmetic (setpoint, observation, reward terms)
    is written on arrays: one env is the one-row case of
    :mod:`cir_gym.envs.agent_ready_vector`'s N copies.
    """

    task_class: ClassVar[type[RobotEnv]]
    robot_name: ClassVar[str] = "iiwa14"

    def __init__(
        self,
        task: RobotEnv,
        *,
        control_freq: float,
        max_translation: float,
        max_rotation: float,
        max_setpoint_offset: float,
        max_setpoint_angle: float,
        impedance_stiffness: float,
        impedance_rotational_stiffness: float,
        damping_ratio: float,
        variable_stiffness: bool,
        action_rate_weight: float,
        failure_penalty: float,
        charge_unplayed_steps: bool,
        render_mode: str | None,
        width: int,
        height: int,
    ) -> None:
        lo, hi = POLICY_FREQ_RANGE
        control_freq = check_number("control_freq", control_freq, lo, hi)
        ratio = IMPEDANCE_FREQ / control_freq
        if abs(ratio - round(ratio)) > 1e-9 * ratio:
            raise InvalidArgument(
                f"control_freq must be {IMPEDANCE_FREQ:g} Hz (the impedance loop) divided by an "
                f"integer, in [{lo:g}, {hi:g}] Hz (10, 12.5, 20, 25, 50, ...), got {control_freq!r}"
            )
        self.substeps = round(ratio)  # task control steps (impedance-loop steps) per policy step
        self.max_translation = check_number("max_translation", max_translation, 0.0, 0.02,
                                            low_open=True)
        self.max_rotation = check_number("max_rotation", max_rotation, 0.0, 0.2, low_open=True)
        self.max_setpoint_offset = check_number(
            "max_setpoint_offset", max_setpoint_offset, 0.0, 0.2, low_open=True
        )
        self.max_setpoint_angle = check_number(
            "max_setpoint_angle", max_setpoint_angle, 0.0, 1.0, low_open=True
        )
        (k_lo, k_hi), (kr_lo, kr_hi) = STIFFNESS_RANGE
        k_t = check_number("impedance_stiffness", impedance_stiffness, k_lo, k_hi)
        k_r = check_number(
            "impedance_rotational_stiffness", impedance_rotational_stiffness, kr_lo, kr_hi
        )
        self.stiffness = np.r_[np.full(3, k_t), np.full(3, k_r)]  # K_p (6,)
        self.damping_ratio = check_number("damping_ratio", damping_ratio, 0.1, 2.0)
        self.variable_stiffness = check_flag("variable_stiffness", variable_stiffness)
        self.action_rate_weight = check_number("action_rate_weight", action_rate_weight, 0.0, 10.0)
        self.failure_penalty = check_number("failure_penalty", failure_penalty, 0.0, 1e4)
        self.charge_unplayed_steps = check_flag("charge_unplayed_steps", charge_unplayed_steps)
        self.task = task
        if task.max_steps % self.substeps:
            raise InvalidArgument(
                f"episode_duration must be a whole number of policy periods (1/{control_freq:g} "
                f"s); the task has {task.max_steps} steps of {task.dt:g} s"
            )
        if not math.isclose(1.0 / task.dt, IMPEDANCE_FREQ, rel_tol=1e-9):
            raise InvalidArgument(f"the task must run at {IMPEDANCE_FREQ:g} Hz, got {1 / task.dt}")
        super().__init__(
            task.model,
            control_freq=control_freq,
            episode_duration=task.max_steps * task.dt,
            render_mode=render_mode,
            width=width,
            height=height,
            camera=task.camera,
        )
        self.data = task.data  # one simulation: the task's
        self.torque_limit = task.torque_limit.copy()
        context = task.controller_context()
        self.task_context = context
        self.nominal = tool_robot(context, self._tcp_offset(context))
        gains = ImpedanceGains(self.stiffness, np.zeros(6))  # K_d set at reset
        self.impedance = CartesianImpedance(self.nominal, "tcp", gains, np.zeros(self.nominal.n))
        self.action_scale = np.r_[np.full(3, self.max_translation), np.full(3, self.max_rotation)]
        dim = 12 if self.variable_stiffness else 6
        self.action_space = spaces.Box(-1.0, 1.0, (dim,), dtype=np.float32)
        obs_spaces = dict(task.observation_space.spaces)
        obs_spaces["setpoint_offset"] = spaces.Box(
            -_OFFSET_BOUND, _OFFSET_BOUND, (6,), dtype=np.float64
        )
        if self.variable_stiffness:
            obs_spaces["stiffness"] = spaces.Box(_K_LOW, _K_HIGH, (6,), dtype=np.float64)
        self.observation_space = spaces.Dict(obs_spaces)
        self.p_d = np.zeros(3)  # setpoint position (m, world)
        self.R_d = np.eye(3)  # setpoint rotation (site → world)
        self.K_p = self.stiffness.copy()
        self.K_d = np.zeros(6)
        self._m_eff = np.ones(6)  # diag Λ(q₀) (kg, kg m²): the damping's design inertia
        self._a_prev = np.zeros(dim)
        self._task_obs: dict[str, np.ndarray] = {}
        self._k = 0

    # ------------------------------------------------------------------ task hooks
    def _tcp_offset(self, context: TaskContext) -> float | None:
        """The controlled point beyond the flange (m), or None for the robot file's ``tcp``."""
        return None

    def _task_term(self, info: dict[str, Any]) -> Any:
        """The task's reward term of one task control step, in [−1, 0]: a number from one
        env's info, (N,) from N copies' step infos."""
        raise NotImplementedError

    def _task_terms(self) -> tuple[str, ...]:
        """Names of the reward terms (``info["reward_<name>"]``) besides task and action rate."""
        return ("failure",)

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        obs, info = self.task.reset(seed=seed, options=options)
        self._start(obs)
        return self._obs(), info

    def _start(self, task_obs: dict[str, np.ndarray]) -> None:
        """Hold still where the task starts (its first observation ``task_obs``): the
        setpoint at the start pose, K_p the configured stiffness, K_d critical for the design
        inertia diag Λ(q₀), the posture regulator's rest at q₀."""
        q = task_obs["q"]
        imp = self.impedance
        imp.q_rest[:] = q
        self._m_eff = np.diag(imp.task_inertia(q)).copy()
        self.K_p = self.stiffness.copy()
        self.K_d = critical_damping(self.K_p, self._m_eff, self.damping_ratio)
        imp.gains = ImpedanceGains(self.K_p, self.K_d)
        self.p_d, self.R_d = imp.pose(q)
        self._a_prev[:] = 0.0
        self._k = 0
        self._task_obs = task_obs

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        a = self._check_action(action)[0]
        imp = self.impedance
        self.p_d, self.R_d, self.K_p, self.K_d = self._move_setpoint(
            a, *imp.pose(self._task_obs["q"]), self.p_d, self.R_d, self.K_p, self.K_d,
            self._m_eff,
        )
        task_sum, played = 0.0, 0
        terminated = truncated = False
        info: dict[str, Any] = {}
        obs = self._task_obs
        for _ in range(self.substeps):
            tau = imp.torque(obs["q"], obs["qd"], self.p_d, self.R_d, self.K_p, self.K_d)
            u = np.clip(tau / self.torque_limit, -1.0, 1.0)
            obs, _, terminated, truncated, info = self.task.step(u)
            task_sum += self._task_term(info)
            played += 1
            if terminated or truncated:
                break
        self._task_obs = obs
        self._k += 1
        success = bool(info.get("is_success", False))
        failed = bool(terminated and not success)
        terms = self._reward_terms(task_sum / played, a, self._a_prev, success, failed, self._k)
        self._a_prev[:] = a
        reward = math.fsum(float(v) for v in terms.values())
        out = {k: v for k, v in info.items() if not k.startswith("reward_")}
        out.update({f"reward_{k}": float(v) for k, v in terms.items()})
        out["task_steps"] = played
        out["diverged"] = bool(info.get("diverged", False))
        return self._obs(), reward, bool(terminated), bool(truncated), out

    def _reward_terms(
        self, task_mean: Any, a: np.ndarray, a_prev: np.ndarray, success: Any, failed: Any,
        k: Any,
    ) -> dict[str, Any]:
        """The reward's terms of a policy step (Rewards section): numbers for one env, (N,)
        arrays for N copies. ``task_mean``: the mean task term over the step's task control
        steps; ``a``, ``a_prev`` (..., dim): this and the previous action; ``success``,
        ``failed``: the task's end; ``k``: policy steps played, this one included."""
        terms = {
            "task": np.maximum(task_mean, -1.0),
            "action_rate": -self.action_rate_weight
            * np.sum((a - a_prev) ** 2, axis=-1) / (4 * a.shape[-1]),
        }
        terms.update(self._end_terms(success, failed, k))
        return terms

    def _end_terms(self, success: Any, failed: Any, k: Any) -> dict[str, Any]:
        """The terminal terms: a failure (the task terminated without success) loses
        ``failure_penalty`` and, with ``charge_unplayed_steps``, the worst reward of every
        policy step it does not play, (T − k)(1 + ``action_rate_weight``)."""
        unplayed = (self.max_steps - k) * self.worst_step_reward()
        charge = unplayed if self.charge_unplayed_steps else 0.0
        return {"failure": np.where(failed, -(self.failure_penalty + charge), 0.0)}

    def worst_step_reward(self) -> float:
        """The magnitude of the worst reward of a step that does not end the episode."""
        return 1.0 + self.action_rate_weight

    # ------------------------------------------------------------------ the setpoint
    def _move_setpoint(
        self, a: np.ndarray, p: np.ndarray, R: np.ndarray, p_d: np.ndarray, R_d: np.ndarray,
        K_p: np.ndarray, K_d: np.ndarray, m_eff: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Apply policy actions a (..., dim) to setpoints (p_d, R_d) and gains (K_p, K_d)
        from the current poses (p, R): the setpoint moves by [δp; δφ] = a[:6] ⊙ action_scale
        and is clamped (:func:`move_setpoint`); with ``variable_stiffness`` a[6:] sets K_p
        (:func:`stiffness_from_action`) and K_d (critical for ``m_eff``). One env or N copies
        ((N, ...) arrays). Returns the new (p_d, R_d, K_p, K_d)."""
        p_d, R_d = move_setpoint(
            p_d, R_d, a[..., :6] * self.action_scale, p, R, self.max_setpoint_offset,
            self.max_setpoint_angle,
        )
        if self.variable_stiffness:
            K_p = stiffness_from_action(a[..., 6:])
            K_d = critical_damping(K_p, m_eff, self.damping_ratio)
        return p_d, R_d, K_p, K_d

    def setpoint_offset(self) -> np.ndarray:
        """[p_d − p; log(R_d Rᵀ)] (6,): the setpoint relative to the current pose (m, rad,
        world frame), from the nominal model at the measured q."""
        return pose_error(self.p_d, self.R_d, *self.impedance.pose(self._task_obs["q"]))

    def _obs(self) -> dict[str, np.ndarray]:
        p, R = self.impedance.pose(self._task_obs["q"])
        return self._observation(self._task_obs, p, R, self.p_d, self.R_d, self.K_p)

    def _observation(
        self, task_obs: dict[str, np.ndarray], p: np.ndarray, R: np.ndarray, p_d: np.ndarray,
        R_d: np.ndarray, K_p: np.ndarray,
    ) -> dict[str, np.ndarray]:
        """The observation: the task's ``task_obs`` plus the setpoint relative to the pose
        (p, R) and, with ``variable_stiffness``, K_p. One env or N copies ((N, ...) arrays)."""
        obs = dict(task_obs)
        obs["setpoint_offset"] = np.clip(pose_error(p_d, R_d, p, R), -_OFFSET_BOUND, _OFFSET_BOUND)
        if self.variable_stiffness:
            obs["stiffness"] = np.clip(K_p, _K_LOW, _K_HIGH)
        return obs

    # ------------------------------------------------------------------ metrics, pictures
    def episode_metrics(self) -> dict[str, float]:
        """The task's metrics of the episode so far."""
        return self.task.episode_metrics()  # type: ignore[attr-defined]

    def draw_task(self, scene: Any) -> None:
        self.task.draw_task(scene)

    def caption(self) -> str:
        return self.task.caption()

    def controller_context(self) -> TaskContext:
        """The task's nominal facts; the action is a setpoint increment of the impedance loop,
        whose rate, stiffness K_p (6,) and damping ratio ζ (K_d = 2ζ√(K_p diag Λ(q₀))) the
        extras carry (``impedance_freq``, ``impedance_stiffness``,
        ``impedance_damping_ratio``)."""
        ctx = self.task_context
        return TaskContext(
            robot=ctx.robot,
            dt=self.dt,
            action_kind="impedance_setpoint_increment",
            action_scale=self.action_scale.copy(),
            site="tcp",
            extras={
                **ctx.extras,
                "impedance_freq": IMPEDANCE_FREQ,
                "impedance_stiffness": self.stiffness.copy(),
                "impedance_damping_ratio": self.damping_ratio,
                "variable_stiffness": self.variable_stiffness,
            },
        )

    def close(self) -> None:
        self.task.close()
        super().close()


_COMMON_ACTION = """
    ``Box(-1, 1, (6,), float32)`` (``variable_stiffness=True``: (12,)). a[:3] moves the pose
    setpoint's position by a[:3] · ``max_translation`` (m, world frame), a[3:6] turns it by the
    rotation vector a[3:6] · ``max_rotation`` (rad, world frame: R_d ← exp(δφ) R_d); the setpoint
    is then clamped to ``max_setpoint_offset`` (m) and ``max_setpoint_angle`` (rad) from the
    current pose, which bounds the static force the arm can exert to K_p × the offset. With
    ``variable_stiffness``, a[6:12] sets the stiffness K_p per axis on a log scale,
    K = K_lo (K_hi/K_lo)^((a+1)/2), (K_lo, K_hi) = (100, 5000) N/m and (5, 250) N m/rad, and
    the damping follows (ζ = ``damping_ratio``). An action of zeros holds the setpoint: the arm
    holds still. Finite values outside [-1, 1] are clipped; NaN/inf or a wrong shape raise
    ``ValueError``.
"""

_COMMON_LOOP = """
    The env-side loop is chapter 6's impedance law in its PD + gravity form
    (``control-laws.md`` §5 "Operational space: PD + gravity", the compliance of §6
    "Impedance control" without force measurement; :mod:`cir_gym.impedance`):
    τ = Jᵀ(q)(K_p x̃ − K_d J(q) q̇) + g(q) + Nᵀ τ₀, x̃ = [p_d − p; log(R_d Rᵀ)], run at every
    500-Hz control step of the task's torque interface on the measured q, q̇, with τ clipped
    to τ_max. It uses the nominal model the task hands its controllers
    (``controller_context()``: the robot file with the tool's mass at its centre of mass),
    never the simulator. K_d = 2ζ √(K_p diag Λ(q₀)) (Λ the task-space inertia at the start
    posture); τ₀ = 10 (q₀ − q) − 2 q̇ N m holds the self-motion in the null space. Built in by
    construction, and not by the torque interface: gravity compensation (tool included), a
    stable compliant pose regulator, and the bounded setpoint.
"""

_COMMON_REWARD = """
    On one scale: every step that does not end the episode earns r ∈ [−(1 + w_a), 0]
    (w_a = ``action_rate_weight``), each term in ``info["reward_<name>"]``:
    - r_task ∈ [−1, 0]: the mean over the policy step's task control steps of {task_term};
    - r_action_rate = −w_a ‖a_k − a_{{k−1}}‖² / (4 dim(a)) ∈ [−w_a, 0];
{success_term}    - r_failure = −``failure_penalty`` − (T − k)(1 + w_a) on a failure (the task terminated
      without success: {failures}), T the episode's policy steps and k the steps played: the
      worst reward of each unplayed step is charged, so failing early never raises the return,
      at any discount γ ≤ 1 (``charge_unplayed_steps=False``: the penalty alone).
    No terminal term exceeds an episode's worst return, T (1 + w_a), by more than
    ``failure_penalty`` (10 by default: half a second of the worst reward at 20 Hz).
"""


class PegInHoleImpedanceEnv(ImpedanceTaskEnv):
    __doc__ = (
        """PegInHole (chapter 6) for agents: pose-setpoint increments of a Cartesian impedance
    loop at 20 Hz.

    ## Description
    The task of ``cir_gym/PegInHole-v2`` (:class:`~cir_gym.envs.peg_in_hole.PegInHoleEnv`,
    whose docstring describes the scene, the hole-pose uncertainty and the contact physics),
    played through its torque interface by an env-side Cartesian impedance loop at the peg
    tip. The policy acts at ``control_freq`` (default 20 Hz, 25 impedance-loop steps per
    action): what practitioners train on (robosuite's operational-space controller at 20 Hz,
    Isaac Lab Factory's and IndustReal's task-space impedance; Martín-Martín et al. 2019 found
    impedance-space actions the most sample-efficient). The same seeds give the same hole
    poses as PegInHole-v2; metrics and success are PegInHole-v2's, unchanged.
"""
        + _COMMON_LOOP
        + """
    Contact forces rise quickly on the sharp-edged block: the arm's inertia at the tip
    (Λ_zz ≈ 11 kg at the start) meeting the face at v gives ≈ m v / 1 ms, so approaching faster
    than ~1 cm/s exceeds the 100-N force limit whatever the stiffness.

    ## Action Space"""
        + _COMMON_ACTION
        + """    Defaults: 2 mm and 0.02 rad per step (0.04 m/s and 0.4 rad/s at 20 Hz, close to the
    position interface's 0.05 m/s and 0.5 rad/s). The nominal hole frame is the world's
    (PegInHole's ``hole_quat`` is the identity), so the world axes are the hole's.

    ## Observation Space
    PegInHole-v2's ``Dict`` (q, qd, peg_pos, peg_quat, peg_twist, wrench — the wrist F/T
    reading —, hole_pos, hole_quat), plus:

    | key | shape | meaning | bounds | unit |
    |---|---|---|---|---|
    | setpoint_offset | 6 | the setpoint relative to the peg tip, [p_d − p; log(R_d Rᵀ)], world | ±1, ±π | m, rad |
    | stiffness | 6 | K_p (only with ``variable_stiffness``) | see Action Space | N/m, N m/rad |

    ## Rewards"""
        + _COMMON_REWARD.format(
            task_term="−(min(‖p_tip − p_goal‖/0.05 m, 1) + w_f min(F/F_lim, 1)²)/(1 + w_f), "
            "PegInHole's distance term and its force term (F the largest single contact force "
            "of the task step, F_lim = ``force_limit``, w_f = ``force_weight``)",
            success_term="    - r_success = ``success_bonus`` on the step the peg is inserted;\n",
            failures="the force limit or a divergence",
        )
        + """
    ## Starting State
    PegInHole-v2's: at rest, the tip ``start_height`` above the nominal hole, aligned with it;
    the setpoint at that pose (an action of zeros holds it).

    ## Episode End
    PegInHole-v2's, at the policy step in which the task's step ends: terminated on insertion
    (success), on the force limit or on a divergence (``info["diverged"]``); truncated after
    ``episode_duration`` (240 policy steps by default). ``info`` holds the task's last step's
    entries (``contact_force``, ``depth``, ``two_point_contact``, ``wedged``, ``jammed``, …),
    ``task_steps`` (task steps played in this policy step) and, at the end, the task's
    ``episode_metrics`` and ``is_success``.

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | sensor | "ati_gamma" | PegInHole's wrist F/T sensor preset |
    | clearance | 0.0005 | PegInHole's diametral clearance (m) |
    | chamfer | 0.0 | PegInHole's chamfer width (m) |
    | position_uncertainty | 0.002 | PegInHole's hole-position uncertainty (m) |
    | tilt_uncertainty | 2.0 | PegInHole's hole-tilt uncertainty (degrees) |
    | force_limit | 100.0 | PegInHole's force limit (N) |
    | start_height | 0.01 | PegInHole's initial tip height (m) |
    | success_depth | 0.9 | PegInHole's success depth (fraction of the bore) |
    | episode_duration | 12.0 | s, a whole number of policy periods |
    | control_freq | 20.0 | policy rate (Hz): 500 Hz divided by an integer, in [10, 50] |
    | max_translation | 0.002 | setpoint translation per step at |a| = 1 (m, ≤ 0.02) |
    | max_rotation | 0.02 | setpoint rotation per step at |a| = 1 (rad, ≤ 0.2) |
    | max_setpoint_offset | 0.01 | largest distance of the setpoint from the tip (m) |
    | max_setpoint_angle | 0.1 | largest angle of the setpoint from the tip's orientation (rad) |
    | impedance_stiffness | 1000.0 | translational stiffness K_p (N/m, in [100, 5000]) |
    | impedance_rotational_stiffness | 50.0 | rotational stiffness K_p (N m/rad, in [5, 250]) |
    | damping_ratio | 1.0 | ζ of the damping K_d (in [0.1, 2]) |
    | variable_stiffness | False | the action also sets the stiffness (12 dimensions) |
    | force_weight | 1.0 | w_f, weight of the force term in r_task |
    | action_rate_weight | 0.01 | w_a, weight of the action-rate term |
    | success_bonus | 10.0 | reward on insertion |
    | failure_penalty | 10.0 | reward lost on a failure, on top of the unplayed steps' charge |
    | charge_unplayed_steps | True | a failure also loses the worst reward of each unplayed step |
    | render_mode | None | None, "human", "rgb_array" or "rgb_array_list" |
    | width | 480 | frame width (px) |
    | height | 480 | frame height (px) |

    ## Metrics
    PegInHole-v2's (``insertion_time`` primary, ``peak_force``, ``peak_net_force``,
    ``mean_force``, ``force_impulse``, ``jammed_time``, ``final_depth``), read at the task's
    physics-step resolution from the task itself: an agent here and a controller on
    PegInHole-v2 are scored on the same seeds by the same code.

    ## Reference controllers
    ``impedance_insertion`` and ``impedance_spiral`` (:mod:`cir_gym.baselines.setpoint`): the
    insertion strategy of the hybrid laws as setpoint motion, f = K·Δx. The leaderboard ranks
    every policy of this variant in PegInHole-v2's tables (labelled ``[PegInHoleImpedance-v0]``)
    beside the torque-interface controllers (hybrid_force_position, hybrid_spiral,
    position_spiral, position_only, admittance), on the same seeds. An action of zeros is the hold-still policy of
    the normalized score (:mod:`cir_gym.scoring.normalized`).

    ## Version History
    - v0: initial version (on PegInHole-v2's task).
    """
    )

    task_class: ClassVar[type[RobotEnv]] = PegInHoleEnv
    metric_specs = PegInHoleEnv.metric_specs
    primary_metric = PegInHoleEnv.primary_metric
    leaderboard_variants: ClassVar[dict[str, dict[str, Any]]] = dict(
        PegInHoleEnv.leaderboard_variants
    )
    reward_arguments: ClassVar[frozenset[str]] = frozenset((
        "force_weight", "action_rate_weight", "success_bonus", "failure_penalty",
        "charge_unplayed_steps",
    ))

    def __init__(
        self,
        sensor: str = "ati_gamma",
        clearance: float = 0.0005,
        chamfer: float = 0.0,
        position_uncertainty: float = 0.002,
        tilt_uncertainty: float = 2.0,
        force_limit: float = 100.0,
        start_height: float = 0.01,
        success_depth: float = 0.9,
        episode_duration: float = 12.0,
        control_freq: float = 20.0,
        max_translation: float = 0.002,
        max_rotation: float = 0.02,
        max_setpoint_offset: float = 0.01,
        max_setpoint_angle: float = 0.1,
        impedance_stiffness: float = 1000.0,
        impedance_rotational_stiffness: float = 50.0,
        damping_ratio: float = 1.0,
        variable_stiffness: bool = False,
        force_weight: float = 1.0,
        action_rate_weight: float = 0.01,
        success_bonus: float = 10.0,
        failure_penalty: float = 10.0,
        charge_unplayed_steps: bool = True,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
    ) -> None:
        self.force_weight = check_number("force_weight", force_weight, 0.0, 100.0)
        self.success_bonus = check_number("success_bonus", success_bonus, 0.0, 1e4)
        self.task_arguments: dict[str, Any] = dict(
            control="torque",
            sensor=sensor,
            clearance=clearance,
            chamfer=chamfer,
            position_uncertainty=position_uncertainty,
            tilt_uncertainty=tilt_uncertainty,
            force_limit=force_limit,
            start_height=start_height,
            success_depth=success_depth,
            control_freq=IMPEDANCE_FREQ,
            episode_duration=episode_duration,
        )
        task = PegInHoleEnv(**self.task_arguments)
        self.force_limit = task.force_limit
        super().__init__(
            task,
            control_freq=control_freq,
            max_translation=max_translation,
            max_rotation=max_rotation,
            max_setpoint_offset=max_setpoint_offset,
            max_setpoint_angle=max_setpoint_angle,
            impedance_stiffness=impedance_stiffness,
            impedance_rotational_stiffness=impedance_rotational_stiffness,
            damping_ratio=damping_ratio,
            variable_stiffness=variable_stiffness,
            action_rate_weight=action_rate_weight,
            failure_penalty=failure_penalty,
            charge_unplayed_steps=charge_unplayed_steps,
            render_mode=render_mode,
            width=width,
            height=height,
        )

    def _tcp_offset(self, context: TaskContext) -> float | None:
        return float(context.extras["tip_offset"])  # the peg tip

    def _task_term(self, info: dict[str, Any]) -> Any:
        force = np.minimum(info["contact_force"] / self.force_limit, 1.0) ** 2
        return (info["reward_distance"] - self.force_weight * force) / (1.0 + self.force_weight)

    def _end_terms(self, success: Any, failed: Any, k: Any) -> dict[str, Any]:
        return {"success": np.where(success, self.success_bonus, 0.0),
                **super()._end_terms(success, failed, k)}


class AdmittanceContactImpedanceEnv(ImpedanceTaskEnv):
    __doc__ = (
        """AdmittanceContact (chapter 6) for agents: pose-setpoint increments of a Cartesian
    impedance loop at 20 Hz.

    ## Description
    The task of ``cir_gym/AdmittanceContact-v2``
    (:class:`~cir_gym.envs.admittance_contact.AdmittanceContactEnv`: press the tool on a
    compliant plate with the reference force f̄ while wiping a path; its docstring describes
    the scene, the surface errors and the sensor), played through its torque interface by an
    env-side Cartesian impedance loop at the tool tip (``tcp``). The policy acts at
    ``control_freq`` (default 20 Hz, 25 impedance-loop steps per action). The same seeds give
    the same surfaces, forces and paths as AdmittanceContact-v2; metrics and success are its
    own, unchanged.
"""
        + _COMMON_LOOP
        + """
    The force the tool exerts at rest is K_p,z × the setpoint's depth below the contact point
    (a 20-N reference at the default 1000 N/m: 2 cm), in series with the plate's spring.

    ## Action Space"""
        + _COMMON_ACTION
        + """    Defaults: 5 mm and 0.05 rad per step (0.1 m/s and 1 rad/s at 20 Hz; the wiping path
    peaks at 0.079 m/s).

    ## Observation Space
    AdmittanceContact-v2's ``Dict`` (q, qd, tool_pos, tool_quat, tool_vel, tool_angvel,
    wrench — the wrist F/T reading —, f_ref, tool_pos_ref, tool_vel_ref, setpoint_pos,
    setpoint_quat), where ``setpoint_pos`` and ``setpoint_quat`` hold the impedance loop's
    setpoint as of the task's last step (the torque interface reports the tool's pose there;
    the setpoint moves only at policy steps), plus:

    | key | shape | meaning | bounds | unit |
    |---|---|---|---|---|
    | setpoint_offset | 6 | the setpoint relative to the tool tip, [p_d − p; log(R_d Rᵀ)], world | ±1, ±π | m, rad |
    | stiffness | 6 | K_p (only with ``variable_stiffness``) | see Action Space | N/m, N m/rad |

    ## Rewards"""
        + _COMMON_REWARD.format(
            task_term="(r_force + r_path)/(1 + w_p), AdmittanceContact's force and path terms "
            "(``force_scale``, ``path_scale``, w_p = ``path_weight``)",
            success_term="",
            failures="the force limit or a divergence",
        )
        + """
    ## Starting State
    AdmittanceContact-v2's: at rest at ``START_Q``, the tip 3 cm above the nominal surface;
    the setpoint at that pose (an action of zeros holds it).

    ## Episode End
    AdmittanceContact-v2's, at the policy step in which the task's step ends: terminated on
    the force limit or a divergence (``info["diverged"]``), truncated after
    ``episode_duration`` (100 policy steps by default). ``info`` holds the task's last step's
    entries (``contact_force``, ``in_contact``, ``plate_load``, …), ``task_steps`` and, at the
    end, the task's ``episode_metrics`` and ``is_success``.

    ## Arguments
    | argument | default | meaning |
    |---|---|---|
    | episode_duration | 5.0 | s, a whole number of policy periods |
    | timestep | 0.00025 | AdmittanceContact's physics step (s) |
    | stiffness | 10000.0 | AdmittanceContact's surface stiffness (N/m) |
    | damping | 20.0 | AdmittanceContact's surface damping (N s/m) |
    | force_ref | None | AdmittanceContact's reference force (N); None = drawn per episode |
    | height_error | 0.005 | AdmittanceContact's surface height error (m) |
    | tilt_error | 0.0524 | AdmittanceContact's surface tilt (rad) |
    | randomize | False | AdmittanceContact's per-reset draw of stiffness, damping, sensor bias |
    | sensor | "robotiq_ft300" | AdmittanceContact's sensor preset |
    | sensor_bias | None | AdmittanceContact's sensor bias |
    | sensor_noise | None | AdmittanceContact's sensor noise |
    | sensor_resolution | None | AdmittanceContact's sensor quantum |
    | sensor_rate | None | AdmittanceContact's sensor sample rate |
    | sensor_cutoff | None | AdmittanceContact's sensor low-pass cut-off |
    | sensor_delay | None | AdmittanceContact's sensor delay |
    | force_limit | 100.0 | AdmittanceContact's force limit (N) |
    | settle_time | 0.5 | AdmittanceContact's settling time before scoring (s) |
    | success_threshold | 1.0 | AdmittanceContact's success threshold (N) |
    | force_scale | 10.0 | AdmittanceContact's force-term width (N) |
    | path_scale | 0.01 | AdmittanceContact's path-term width (m) |
    | path_weight | 0.5 | w_p, AdmittanceContact's path-term weight |
    | control_freq | 20.0 | policy rate (Hz): 500 Hz divided by an integer, in [10, 50] |
    | max_translation | 0.005 | setpoint translation per step at |a| = 1 (m, ≤ 0.02) |
    | max_rotation | 0.05 | setpoint rotation per step at |a| = 1 (rad, ≤ 0.2) |
    | max_setpoint_offset | 0.05 | largest distance of the setpoint from the tip (m) |
    | max_setpoint_angle | 0.2 | largest angle of the setpoint from the tool's orientation (rad) |
    | impedance_stiffness | 1000.0 | translational stiffness K_p (N/m, in [100, 5000]) |
    | impedance_rotational_stiffness | 50.0 | rotational stiffness K_p (N m/rad, in [5, 250]) |
    | damping_ratio | 1.0 | ζ of the damping K_d (in [0.1, 2]) |
    | variable_stiffness | False | the action also sets the stiffness (12 dimensions) |
    | action_rate_weight | 0.01 | w_a, weight of the action-rate term |
    | failure_penalty | 10.0 | reward lost on a failure, on top of the unplayed steps' charge |
    | charge_unplayed_steps | True | a failure also loses the worst reward of each unplayed step |
    | render_mode | None | None, "human", "rgb_array" or "rgb_array_list" |
    | width | 480 | frame width (px) |
    | height | 480 | frame height (px) |

    ## Metrics
    AdmittanceContact-v2's (``force_rms_error`` primary, ``peak_overshoot``,
    ``contact_loss``, ``path_error``, ``max_force``), read at the task's physics-step
    resolution from the task itself, and its success (no stop, force RMS error below
    ``success_threshold``, contact loss below 1 %).

    ## Reference controllers
    :mod:`cir_gym.baselines.setpoint`: ``impedance_setpoint``, impedance control with the
    setpoint sunk by the designed equilibrium f̄ (1/K + 1/k̂) (no force feedback);
    ``admittance_setpoint`` and ``implicit_force_setpoint``, the course's admittance and
    implicit force control with this impedance loop as their inner motion loop (the force
    error moves the setpoint's depth; designed on the loop in series with the surface, at the
    policy rate). The leaderboard ranks every
    policy of this variant in AdmittanceContact-v2's tables (labelled
    ``[AdmittanceContactImpedance-v1]``) beside the torque-interface controllers (impedance,
    admittance, explicit_force, implicit_force, parallel_force_position), on the same seeds. An action of zeros is the hold-still policy
    of the normalized score (:mod:`cir_gym.scoring.normalized`).

    ## Version History
    - v0: initial version (on AdmittanceContact-v1's task).
    - v1: on AdmittanceContact-v2's task: ``max_force`` and the force limit read the whole
      force (normal and friction) of the largest single contact; the loop, the observations
      and the reward are unchanged.
    """
    )

    task_class: ClassVar[type[RobotEnv]] = AdmittanceContactEnv
    metric_specs = AdmittanceContactEnv.metric_specs
    primary_metric = AdmittanceContactEnv.primary_metric
    leaderboard_variants: ClassVar[dict[str, dict[str, Any]]] = dict(
        AdmittanceContactEnv.leaderboard_variants
    )
    reward_arguments: ClassVar[frozenset[str]] = frozenset((
        "force_scale", "path_scale", "path_weight", "action_rate_weight", "failure_penalty",
        "charge_unplayed_steps",
    ))

    def __init__(
        self,
        episode_duration: float = 5.0,
        timestep: float = TIMESTEP,
        stiffness: float = 10000.0,
        damping: float = 20.0,
        force_ref: float | None = None,
        height_error: float = 0.005,
        tilt_error: float = 0.0524,
        randomize: bool = False,
        sensor: str = "robotiq_ft300",
        sensor_bias: Any = None,
        sensor_noise: Any = None,
        sensor_resolution: Any = None,
        sensor_rate: float | None = None,
        sensor_cutoff: float | None = None,
        sensor_delay: float | None = None,
        force_limit: float = 100.0,
        settle_time: float = 0.5,
        success_threshold: float = 1.0,
        force_scale: float = 10.0,
        path_scale: float = 0.01,
        path_weight: float = 0.5,
        control_freq: float = 20.0,
        max_translation: float = 0.005,
        max_rotation: float = 0.05,
        max_setpoint_offset: float = 0.05,
        max_setpoint_angle: float = 0.2,
        impedance_stiffness: float = 1000.0,
        impedance_rotational_stiffness: float = 50.0,
        damping_ratio: float = 1.0,
        variable_stiffness: bool = False,
        action_rate_weight: float = 0.01,
        failure_penalty: float = 10.0,
        charge_unplayed_steps: bool = True,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
    ) -> None:
        self.task_arguments: dict[str, Any] = dict(
            control="torque",
            control_freq=IMPEDANCE_FREQ,
            episode_duration=episode_duration,
            timestep=timestep,
            stiffness=stiffness,
            damping=damping,
            force_ref=force_ref,
            height_error=height_error,
            tilt_error=tilt_error,
            randomize=randomize,
            sensor=sensor,
            sensor_bias=sensor_bias,
            sensor_noise=sensor_noise,
            sensor_resolution=sensor_resolution,
            sensor_rate=sensor_rate,
            sensor_cutoff=sensor_cutoff,
            sensor_delay=sensor_delay,
            force_limit=force_limit,
            settle_time=settle_time,
            force_scale=force_scale,
            path_scale=path_scale,
            path_weight=path_weight,
            action_rate_weight=0.0,  # the task's term is on torques: not used here
            success_threshold=success_threshold,
        )
        task = AdmittanceContactEnv(**self.task_arguments)
        self.path_weight = task.path_weight
        super().__init__(
            task,
            control_freq=control_freq,
            max_translation=max_translation,
            max_rotation=max_rotation,
            max_setpoint_offset=max_setpoint_offset,
            max_setpoint_angle=max_setpoint_angle,
            impedance_stiffness=impedance_stiffness,
            impedance_rotational_stiffness=impedance_rotational_stiffness,
            damping_ratio=damping_ratio,
            variable_stiffness=variable_stiffness,
            action_rate_weight=action_rate_weight,
            failure_penalty=failure_penalty,
            charge_unplayed_steps=charge_unplayed_steps,
            render_mode=render_mode,
            width=width,
            height=height,
        )

    def _task_term(self, info: dict[str, Any]) -> Any:
        return (info["reward_force"] + info["reward_path"]) / (1.0 + self.path_weight)

    def _observation(
        self, task_obs: dict[str, np.ndarray], p: np.ndarray, R: np.ndarray, p_d: np.ndarray,
        R_d: np.ndarray, K_p: np.ndarray,
    ) -> dict[str, np.ndarray]:
        obs = super()._observation(task_obs, p, R, p_d, R_d, K_p)
        obs["setpoint_pos"] = np.clip(p_d, -2.0, 2.0)
        obs["setpoint_quat"] = traj.quat_from_matrix(R_d)  # (w, x, y, z), w ≥ 0
        return obs
