"""The RedundantIK task, shared by its two arms: spaces, reset, step, reward and metrics.

A kinematic environment: the action is a joint-velocity command integrated exactly over the
control period (q ← q + Δt q̇, then forward kinematics), with no dynamics. A redundant arm
(n > m) tracks a closed task-space path; a secondary objective (manipulability, distance from
joint limits, obstacle clearance) is scored. The arms' documentation pages are
:class:`cir_gym.envs.redundant_ik.RedundantIKEnv` and
:class:`cir_gym.envs.redundant_ik.RedundantIK7Env`; the episode draws are
:mod:`cir_gym.envs.redundant_ik_scene`, the science :mod:`cir_gym.redundancy` and
:mod:`cir_gym.self_motion`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium import spaces

from cir_gym import trajectories as traj
from cir_gym.context import TaskContext
from cir_gym.envs import redundant_ik_scene as scene
from cir_gym.envs.base import RobotEnv
from cir_gym.envs.redundant_ik_config import MANIPULABILITY_WINDOW, RedundantIKRobot
from cir_gym.operational_space import align_quat
from cir_gym.redundancy import (
    OBJECTIVES,
    joint_limit_margin,
    joint_limit_objective,
    manipulability,
    orientation_error,
)
from cir_gym.robot import Robot
from cir_gym.self_motion import Reference, TaskKinematics
from cir_gym.validation import InvalidArgument, check_flag, check_number

__all__ = ["STEP_INFO_KEYS", "TRACE_FIELDS", "RedundantIKBase"]

OBSTACLE_PATH_TRIES = 20  # paths drawn for "obstacle" until an obstacle can be placed
#: a step's info entries (then "orientation_error" for the pose task), in their order
STEP_INFO_KEYS = (
    "reward_tracking", "reward_orientation", "reward_secondary", "reward_velocity",
    "reward_termination", "task_error", "manipulability", "joint_limit_margin", "clearance",
    "joint_limit_violation", "collision", "diverged",
)
#: what the episode's trace holds per control step (m, rad, task units, rad, m)
TRACE_FIELDS = ("task_error", "orientation_error", "manipulability", "joint_limit_margin",
                "clearance")


def _all_numbers(action: np.ndarray) -> bool:
    """True for an object array of real numbers (no bools, strings or other objects)."""
    return all(
        isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)
        for v in action.ravel()
    )


@dataclass(frozen=True)
class DrawnTask:
    """One drawn task, as ``reset(options={"replay": True})`` starts it again."""

    reference: Reference
    obstacle: np.ndarray  # (4,) m: centre (3,) and radius; radius 0: none
    witness: np.ndarray | None  # "obstacle": the clearing motion (K, n) rad
    lower: np.ndarray  # (n,) rad, this episode's joint limits
    upper: np.ndarray
    q0: np.ndarray  # (n,) rad


class RedundantIKBase(RobotEnv):
    """What :class:`RedundantIKEnv` and :class:`RedundantIK7Env` share; a subclass sets
    ``arm`` (its :class:`RedundantIKRobot`) and implements ``_draw_reference``.

    Attributes:
        kin: the task's kinematics (:class:`cir_gym.self_motion.TaskKinematics`).
        reference: this episode's lap (:class:`cir_gym.self_motion.Reference`).
        trace: (T,) structured array, one row per control step with the fields
            ``TRACE_FIELDS``; a terminated episode's rows after its last step hold the stopped
            arm's scores (see ``_score_stopped_arm``).
        lower: (n,) rad, this episode's lower joint limits.
        upper: (n,) rad, this episode's upper joint limits.
        obstacle_centre: (3,) m.
        obstacle_radius: m (0: no obstacle).
    """

    arm: ClassVar[RedundantIKRobot]
    #: arguments that set what the task asks, not a condition it is asked under: an agent
    #: trained for one objective is not scored on another's variant (agents.trained_for)
    agent_task_keys: ClassVar[tuple[str, ...]] = ("objective",)
    #: reset(options={"replay": True}) starts the last drawn task again (TaskReplay)
    replayable_tasks: ClassVar[bool] = True
    reward_arguments: ClassVar[frozenset[str]] = frozenset((
        "error_scales", "secondary_weight", "velocity_weight", "termination_penalty",
        "charge_unplayed_steps",
    ))
    leaderboard_variants: ClassVar[dict[str, dict[str, Any]]] = {
        "manipulability": {"objective": "manipulability"},
        "obstacle": {"objective": "obstacle"},
        "joint limits": {"objective": "joint_limits"},
    }
    primary_metric: ClassVar[str] = "rms_task_error"
    #: what each variant is ranked on after the success rate: its own objective's metric
    leaderboard_primary_metrics: ClassVar[dict[str, str]] = {
        "manipulability": "min_manipulability",
        "obstacle": "min_clearance",
        "joint limits": "min_joint_limit_margin",
    }

    def __init__(
        self,
        *,
        objective: str = "manipulability",
        control_freq: float,
        episode_duration: float,
        joint_window: float,
        initial_error: float = 0.0,
        error_scales: tuple[float, ...] = (0.1, 0.01, 0.001),
        secondary_weight: float = 0.1,
        velocity_weight: float = 0.01,
        termination_penalty: float = 50.0,
        charge_unplayed_steps: bool = True,
        success_threshold: float = 0.001,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
    ) -> None:
        """See the environment docstrings (## Arguments); the arm's own defaults are its
        subclass's."""
        arm = self.arm
        if objective not in OBJECTIVES:
            raise InvalidArgument(f"objective must be one of {OBJECTIVES}, got {objective!r}")
        self.objective = objective
        self.initial_error = check_number("initial_error", initial_error, 0.0, 0.1)
        self.joint_window = check_number(
            "joint_window", joint_window, 0.0, 2 * np.pi, low_open=True
        )
        self.error_scales = self._check_error_scales(error_scales)  # m
        self.orientation_scales = self.error_scales * 10.0  # rad: 1 mm ↔ 0.01 rad
        self.secondary_weight = check_number("secondary_weight", secondary_weight, 0.0, 10.0)
        self.velocity_weight = check_number("velocity_weight", velocity_weight, 0.0, 10.0)
        self.termination_penalty = check_number(
            "termination_penalty", termination_penalty, 0.0, 1e6
        )
        self.charge_unplayed_steps = check_flag("charge_unplayed_steps", charge_unplayed_steps)
        self.success_threshold = check_number(
            "success_threshold", success_threshold, 0.0, 1.0, low_open=True
        )

        model = scene.build_model(arm)
        self.robot = Robot(model)
        super().__init__(
            model,
            control_freq=control_freq,
            episode_duration=episode_duration,
            render_mode=render_mode,
            width=width,
            height=height,
            camera=arm.camera[0] if arm.camera else -1,
        )
        self.data = self.robot.data  # kinematics only: the robot's MjData is the scene's
        self.robot_name, self.site = arm.robot, arm.site
        self.pos_dim, self.task_dim = arm.pos_dim, arm.task_dim
        self.kin = TaskKinematics(self.robot, arm.site, arm.pos_dim, arm.task_dim)
        self.n = n = self.robot.n
        self.file_lower, self.file_upper = self.robot.lower.copy(), self.robot.upper.copy()
        self.lower, self.upper = self.file_lower.copy(), self.file_upper.copy()
        self.velocity_limit = self.robot.velocity_limit.copy()
        self._obstacle_id = model.geom("obstacle").id
        self.home = model.key("home").qpos[self.robot.qpos_adr].copy()
        # quaternions are observed on the hemisphere ⟨Q, Q_home⟩ ≥ 0 of the home orientation
        self._quat_home = traj.quat_from_matrix(self.kin.pose(self.home)[1])

        self.action_space = spaces.Box(-1.0, 1.0, (n,), dtype=np.float32)
        p = self.pos_dim
        bounds: dict[str, tuple[float, int]] = {
            "q": (2 * np.pi, n),
            "x": (3.0, p),
            "x_ref": (3.0, p),
            "xd_ref": (10.0, p),
        }
        if self.task_dim == 6:
            bounds |= {"quat": (1.0, 4), "quat_ref": (1.0, 4), "omega_ref": (20.0, 3)}
        bounds |= {
            "q_lower": (2 * np.pi, n),
            "q_upper": (2 * np.pi, n),
            "obstacle": (2 * scene.DUMMY_OBSTACLE_CENTRE, p + 1),
        }
        self._obs_high = np.concatenate([np.full(size, b) for b, size in bounds.values()])
        ends = np.cumsum([size for _, size in bounds.values()])
        self._obs_slices = {key: slice(int(end - size), int(end))
                            for (key, (_, size)), end in zip(bounds.items(), ends, strict=True)}
        self.observation_space = spaces.Dict(
            {k: spaces.Box(-b, b, (size,), dtype=np.float64) for k, (b, size) in bounds.items()}
        )

        self.trace = np.zeros(self.max_steps, dtype=[(f, float) for f in TRACE_FIELDS])
        self._task: DrawnTask | None = None  # the last drawn task, for a replay
        self.reference = self._resting_reference()
        self._set_obstacle(scene.DUMMY_OBSTACLE)
        self._witness: np.ndarray | None = None
        self._q = self.home.copy()
        self._q0 = self.home.copy()
        self._k = 0  # control steps played
        self._scored = 0  # rows of the trace that hold the episode's scores

    @staticmethod
    def _check_error_scales(error_scales: Any) -> np.ndarray:
        try:
            scales = np.atleast_1d(np.asarray(error_scales, dtype=float))
        except (TypeError, ValueError) as exc:
            raise InvalidArgument(
                f"error_scales must be positive numbers (m), got {error_scales!r}"
            ) from exc
        if scales.ndim != 1 or scales.size == 0 or not np.all((scales >= 1e-9) & (scales <= 1e3)):
            raise InvalidArgument(
                f"error_scales must be numbers in [1e-9, 1e3] m, got {error_scales!r}"
            )
        return scales

    # ------------------------------------------------------------------ episode setup
    def _time_grid(self) -> np.ndarray:
        """The control instants t_k = k Δt (K + 1,) s of one lap."""
        return np.arange(self.max_steps + 1) * self.dt

    def _resting_reference(self) -> Reference:
        """The home pose held still (before the first reset)."""
        p, R = self.kin.pose(self.home)
        K = self.max_steps + 1
        return Reference(np.tile(p, (K, 1)), np.zeros((K, self.pos_dim)), np.tile(R, (K, 1, 1)),
                         np.tile(self._quat_home, (K, 1)), np.zeros((K, 3)), self.dt)

    def _draw_reference(self) -> Reference:
        """This episode's lap, drawn with ``self.np_random``."""
        raise NotImplementedError

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Draw a new task, or with ``options={"replay": True}`` start the last one again.

        A replay restores the previous reset's reference, obstacle, joint window and q(0)
        exactly and draws nothing (no seed allowed): it costs a forward-kinematics call where
        a draw costs up to ~0.2 s ("obstacle" on the iiwa), so a training wrapper can repeat
        tasks cheaply (:class:`cir_gym.agents.shaping.TaskReplay`). The episode then plays as
        the first play of that task did, for the same actions.
        """
        if self._replay_option(seed, options):
            super().reset()
            assert self._task is not None
            return self._start(self._task)
        super().reset(seed=seed)
        rng, kin = self.np_random, self.kin
        obstacle, witness = scene.DUMMY_OBSTACLE, None
        for _ in range(OBSTACLE_PATH_TRIES):  # "obstacle": a new path until one is placed
            ref = self._draw_reference()
            q0 = kin.solve_ik(self.home.copy(), ref.x[0], ref.R[0])
            if self.objective != "obstacle":
                break
            obstacle, witness = scene.draw_obstacle(
                rng, kin, ref, q0, self.file_lower, self.file_upper, self.velocity_limit,
                self.arm.obstacle_links,
            )
            if witness is not None:
                break
        else:
            raise InvalidArgument(
                f"objective='obstacle': no clearable obstacle on {OBSTACLE_PATH_TRIES} paths of "
                f"{scene.OBSTACLE_DRAWS} draws each with episode_duration="
                f"{self.max_steps * self.dt:g} s: the links must sweep 3 cm past an obstacle "
                f"that a self-motion can also avoid, which a short lap does not allow (the "
                f"default duration placed one on every seed tested, 0-99); use a longer "
                f"episode_duration"
            )
        if self.objective == "manipulability":
            q0 = scene.poorly_conditioned_start(kin, ref, q0, self.file_lower, self.file_upper)
        if self.initial_error > 0:
            d = rng.standard_normal(self.pos_dim)
            offset = self.initial_error * d / np.linalg.norm(d)
            q0 = kin.solve_ik(q0, ref.x[0] + offset, ref.R[0])
        lower, upper = self.file_lower.copy(), self.file_upper.copy()
        if self.objective == "joint_limits":
            lower, upper = scene.narrowed_joint_window(
                rng, kin, q0, self.file_lower, self.file_upper, self.joint_window
            )
        self._task = DrawnTask(ref, obstacle.copy(), witness, lower, upper, q0.copy())
        return self._start(self._task)

    def _replay_option(self, seed: int | None, options: dict | None) -> bool:
        """Validate reset's ``options``: only ``{"replay": bool}``, no seed with a replay."""
        if not options:
            return False
        unknown = set(options) - {"replay"}
        if unknown:
            raise InvalidArgument(f"reset options: unknown {sorted(unknown)}; allowed: 'replay'")
        replay = options.get("replay", False)
        if not isinstance(replay, bool | np.bool_):
            raise InvalidArgument(f"reset option 'replay' must be a bool, got {replay!r}")
        if replay and seed is not None:
            raise InvalidArgument("reset(seed=..., options={'replay': True}): a replay draws "
                                  "nothing, so it takes no seed")
        if replay and self._task is None:
            raise InvalidArgument("reset(options={'replay': True}) before any task was drawn: "
                                  "call reset() first")
        return bool(replay)

    def _set_obstacle(self, obstacle: np.ndarray) -> None:
        """Move the obstacle geom to (centre (3,), radius) and store its observation."""
        centre, radius = obstacle[:3], float(obstacle[3])
        self.obstacle_centre = centre.copy()
        self.obstacle_radius = radius
        self.model.geom_pos[self._obstacle_id] = centre
        self.model.geom_size[self._obstacle_id, 0] = max(radius, 1e-3)
        self.model.geom_rgba[self._obstacle_id, 3] = 0.8 if radius > 0 else 0.0
        self._obstacle = np.concatenate((centre[: self.pos_dim], [radius]))

    def _start(self, task: DrawnTask) -> tuple[dict, dict]:
        """Set up the episode of a drawn task (reference, obstacle, limits, q(0))."""
        self.reference = task.reference
        self._set_obstacle(task.obstacle)
        self._witness = task.witness
        self.lower, self.upper = task.lower.copy(), task.upper.copy()
        self.model.jnt_range[self.robot.joint_ids, 0] = self.lower
        self.model.jnt_range[self.robot.joint_ids, 1] = self.upper
        self._q = task.q0.copy()
        self._q0 = task.q0.copy()
        self._k = 0
        self._scored = 0
        self.trace[:] = 0.0
        info = {"obstacle": self._obstacle.copy(), "q_lower": self.lower.copy(),
                "q_upper": self.upper.copy()}
        return self._obs(*self.kin.pose(self._q)), info

    def clearing_motion(self) -> np.ndarray | None:
        """objective="obstacle": the joint path (K, n) that showed this episode's obstacle can
        be cleared, one configuration every ``LAP_STRIDE`` control steps from q(0) (on the
        task, inside the joint limits, |Δq_j| ≤ q̇_j,max · ``LAP_STRIDE`` Δt, clearance ≥
        ``LAP_CLEARANCE`` at every sample; :mod:`cir_gym.self_motion`). It needs the whole
        reference in advance, so it is a certificate of the instance, not a policy. None for
        the other objectives.
        """
        return None if self._witness is None else self._witness.copy()

    # ------------------------------------------------------------------ step
    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        a, _ = self._check_action(action)
        q = self._q + self.dt * (a * self.velocity_limit)  # q̇ = a ⊙ q̇_max, held over Δt
        margin = joint_limit_margin(q, self.lower, self.upper)
        violation = margin < 0.0
        if violation:
            q = np.clip(q, self.lower, self.upper)  # the joint stops at its limit
            margin = 0.0  # the stopped joint's
        self._q = q
        k = self._k
        self._k = k + 1
        ref = self.reference
        p, R = self.kin.pose(q)
        e_pos = float(np.linalg.norm(ref.x[k + 1] - p))
        e_rot = 0.0
        if self.task_dim == 6:
            e_rot = float(np.linalg.norm(orientation_error(ref.R[k + 1], R)))
        w = manipulability(self.kin.jacobian(q))
        clear = self.kin.capsules.clearance(self.data, self.obstacle_centre, self.obstacle_radius)
        collision = clear < 0.0
        self.trace[k] = (e_pos, e_rot, w, margin, clear)
        self._scored = k + 1

        r_track = -(1.0 - float(np.exp(-(e_pos**2) / self.error_scales**2).mean()))
        r_orient = 0.0
        if self.task_dim == 6:
            r_orient = -(1.0 - float(np.exp(-(e_rot**2) / self.orientation_scales**2).mean()))
        r_secondary = -self.secondary_weight * self._secondary_cost(q, w, clear)
        r_velocity = -self.velocity_weight * float(a @ a) / self.n
        terminated = violation or collision
        r_term = 0.0
        if terminated:
            unplayed = self.max_steps - self._k
            charge = unplayed * self.worst_step_reward() if self.charge_unplayed_steps else 0.0
            r_term = -(self.termination_penalty + charge)
        reward = r_track + r_orient + r_secondary + r_velocity + r_term
        truncated = self._k >= self.max_steps and not terminated
        info: dict[str, Any] = dict(zip(STEP_INFO_KEYS, (
            r_track, r_orient, r_secondary, r_velocity, r_term, e_pos, w, margin, clear,
            violation, collision, False), strict=True))
        if self.task_dim == 6:
            info["orientation_error"] = e_rot
        if terminated:  # scored over the whole lap: the arm stays where it stopped
            self._score_stopped_arm(k, p, R)
        if terminated or truncated:
            metrics = self.episode_metrics()
            info["episode_metrics"] = metrics
            info["is_success"] = self.is_success(metrics, terminated)
        return self._obs(p, R), reward, terminated, truncated, info

    def is_success(self, metrics: dict[str, float], terminated: bool) -> bool:
        """An episode with ``metrics`` succeeded: not terminated, the largest position error
        below ``success_threshold`` (m) and, for the pose task, the largest orientation error
        below ten times it (rad)."""
        ok = metrics["max_task_error"] < self.success_threshold
        if self.task_dim == 6:
            ok = ok and metrics["max_orientation_error"] < 10.0 * self.success_threshold
        return bool(not terminated and ok)

    def worst_step_reward(self) -> float:
        """The magnitude of the worst reward of one step (each kernel term −1, the secondary
        cost 1, ‖a‖² = n): what ``charge_unplayed_steps`` charges per unplayed step."""
        orientation = 1.0 if self.task_dim == 6 else 0.0
        return 1.0 + orientation + self.secondary_weight + self.velocity_weight

    def _score_stopped_arm(self, k: int, p: np.ndarray, R: np.ndarray) -> None:
        """Fill the trace after control step ``k`` as if the arm stayed at the pose (p, R)
        where the episode terminated: its error against the reference it no longer follows
        (which moves on to the end of the lap); manipulability, joint-limit margin and
        clearance of the stopped arm, unchanged."""
        later = np.arange(k + 1, self.max_steps)
        ref = self.reference
        self.trace[later] = self.trace[k]
        self.trace["task_error"][later] = np.linalg.norm(ref.x[later + 1] - p, axis=1)
        if self.task_dim == 6:
            self.trace["orientation_error"][later] = [
                np.linalg.norm(orientation_error(ref.R[j + 1], R)) for j in later
            ]
        self._scored = self.max_steps

    def _check_action(self, action: Any) -> tuple[np.ndarray, bool]:
        """The base class's check, plus: strings or objects are not actions (even "0.1")."""
        array = action
        if not isinstance(array, np.ndarray):
            array = np.asarray(action, dtype=object if isinstance(action, list) else None)
        kind = array.dtype.kind
        if kind in "USO" and not (kind == "O" and _all_numbers(array)):
            raise ValueError(
                f"action must be numbers of shape {self.action_space.shape} in "
                f"[-1, 1], got {action!r}"
            )
        return super()._check_action(action)

    def _secondary_cost(self, q: np.ndarray, w: float, clear: float) -> float:
        """Objective cost in [0, 1]: exp(−w/w₀), −8 w_jl(q), or exp(−clearance / 5 cm)."""
        if self.objective == "manipulability":
            return float(np.exp(-w / self.arm.manipulability_scale))
        if self.objective == "joint_limits":
            return -8.0 * joint_limit_objective(q, self.lower, self.upper)
        return float(np.exp(-max(clear, 0.0) / 0.05))

    # ------------------------------------------------------------------ metrics
    def episode_metrics(self) -> dict[str, float]:
        """Metrics of the episode so far (see ``metric_specs``)."""
        trace = self.trace[: max(self._scored, 1)]
        e, w = trace["task_error"], trace["manipulability"]
        metrics = {
            "rms_task_error": float(np.sqrt(np.mean(e**2))),
            "max_task_error": float(np.max(e)),
        }
        if self.task_dim == 6:
            r = trace["orientation_error"]
            metrics["rms_orientation_error"] = float(np.sqrt(np.mean(r**2)))
            metrics["max_orientation_error"] = float(np.max(r))
        start = int(MANIPULABILITY_WINDOW * self.max_steps)  # the start-up is left out
        metrics |= {
            "min_manipulability": float(np.min(w[start:] if len(w) > start else w)),
            "min_joint_limit_margin": float(np.min(trace["joint_limit_margin"])),
            "min_clearance": float(np.min(trace["clearance"])),
            "joint_drift": float(np.linalg.norm(self._q - self._q0)),
        }
        return metrics

    # ------------------------------------------------------------------ observation
    def _obs(self, p: np.ndarray, R: np.ndarray) -> dict[str, np.ndarray]:
        """The observation at the site pose (p, R) of the current q: new arrays (views of one
        buffer), clipped to their bounds."""
        k, ref = self._k, self.reference
        obs = {"q": self._q, "x": p, "x_ref": ref.x[k], "xd_ref": ref.xd[k]}
        if self.task_dim == 6:
            obs |= {
                "quat": align_quat(traj.quat_from_matrix(R), self._quat_home),
                "quat_ref": ref.quat[k],
                "omega_ref": ref.omega[k],
            }
        obs |= {"q_lower": self.lower, "q_upper": self.upper, "obstacle": self._obstacle}
        return self.observation_of(list(obs.values()))

    def observation_of(self, parts: list[np.ndarray]) -> dict[str, np.ndarray]:
        """The observation dict of its parts in the space's order, each (p_j,) or (N, p_j)
        (rows of N copies): concatenated, clipped to the bounds, and sliced into views of
        that one buffer."""
        flat = np.concatenate(parts, axis=-1)
        np.clip(flat, -self._obs_high, self._obs_high, out=flat)
        return {key: flat[..., part] for key, part in self._obs_slices.items()}

    def controller_context(self) -> TaskContext:
        return TaskContext(
            robot=self.robot_name,
            dt=self.dt,
            action_kind="joint_velocity",
            action_scale=self.velocity_limit.copy(),
            site=self.site,
            extras={
                "objective": self.objective,
                "task_dim": self.task_dim,
                "pos_dim": self.pos_dim,
            },
        )

    # ------------------------------------------------------------------ pictures
    @property
    def step_count(self) -> int:
        """Control steps played in this episode."""
        return self._k

    @property
    def joint_positions(self) -> np.ndarray:
        """q (n,) rad now."""
        return self._q.copy()

    def render(self) -> np.ndarray | None:
        mujoco.mj_camlight(self.model, self.data)  # kinematics alone leaves cameras unset
        return super().render()

    def draw_task(self, scene_: Any) -> None:
        """The reference path, the target, joint-limit warnings, the obstacle's halo."""
        scene.draw_task(self, scene_)

    def caption(self) -> str:
        return scene.caption(self)
