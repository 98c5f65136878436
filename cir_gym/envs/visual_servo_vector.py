"""Native batched VisualServo (eye in hand) on ``mujoco.batch.Batch``.

>>> import cir_gym
>>> envs = cir_gym.make_vec("cir_gym/VisualServo-v1", num_envs=16)  # doctest: +SKIP
>>> obs, infos = envs.reset(seed=0)      # copy i is the single env reset(seed=i)

What is batched (the single env's ``step``, :class:`~cir_gym.envs.visual_servo.VisualServoEnv`,
is the specification; each copy equals it to the tolerance tests/test_visual_servo_vector.py
states):

* **The resolved-rate command.** q̇ = J⁺ V per copy: the flange Jacobians of all copies one
  ``Batch.jac`` (``mj_jac`` at the flange site, as the single env's ``mj_jacSite``), the twist
  rotated by the flange's rotation (the batch's ``site_xmat``), J⁺ V = Jᵀ (J Jᵀ)⁻¹ V as
  stacked solves; a copy whose J Jᵀ is exactly singular takes the least-squares solution, as
  the single env. Then the uniform scaling to the servos' ``ctrlrange``.
* **The physics** of all copies is one ``Batch.step(nstep=frame_skip)``, divergence judged
  per copy by :class:`~cir_gym.envs.vector_base.BatchedTaskEnv`; then one ``Batch.forward``
  to the position stage gives every copy's flange, camera and marker poses.
* **Each copy's scene**: the target's pose (drawn per episode) and the true camera's pose
  error are per-simulation model fields (``Batch.expand``: ``body_pos``, ``body_quat``,
  ``cam_pos``, ``cam_quat``, ``cam_intrinsic``), copied from the template at the copy's
  reset; its true intrinsics (the calibration error) are rows of (f_u, f_v, c_u, c_v).
* **The features**: the markers in each copy's optical frame (:mod:`cir_gym.vision`'s
  ``optical_pose`` and ``camera_points`` on rows) and their projection through its true
  intrinsics on (N, 4, 3) arrays, the image test on (N, 4); the line of sight
  (:func:`cir_gym.vision.visible`'s rule) as ``Batch.ray`` casts of all copies' rays at once,
  a ray that meets a geom enclosing the camera centre cast again from beyond its face. Whether
  a geom encloses the camera centre is MuJoCo's ``mju_rayGeom`` test
  (``cir_gym.vision.encloses``), kept for the episode for the geoms rigid with the camera
  (its own body's weld group) and tested again at each step for the others.
* **Noise, reward, ends**: the projected features' noise is drawn from each copy's own
  generator (8 standard normals per step, the single env's draw), the reward terms, the
  feature error and the position history are the single env's arithmetic on (N, ...) rows;
  episode metrics and success are the template's ``episode_metrics`` on a copy's history.

Supported: ``features="projected"`` without ``obs_image`` (the defaults), both actions
(``"twist"``, ``"joint_velocity"``), and every other argument (``pixel_noise``,
``camera_error``, ``start_offset``, ``start_rotation``, ``control_freq``,
``episode_duration``, the reward's weights, ``width``/``height``). ``features="detected"``
and ``obs_image=True`` render the camera per copy and step (``mujoco.Renderer``, no batched
form): :meth:`unsupported` names them and ``cir_gym.make_vec`` falls back to a
``SyncVectorEnv``, as it does for ``render_mode``. The moving frame is the flange (the
camera's optical frame; VisualServoEnv's ``moving_offset`` is 0) and so is the twist's frame;
VisualServoEyeToHand-v1's batched env
(:mod:`cir_gym.envs.visual_servo_eye_to_hand_vector`) is this class with its own twist frame
(:meth:`VisualServoVectorEnv._twist_rotations`, the fixed camera's) and the plate's offset
(``moving_offset``, which :meth:`VisualServoVectorEnv._moving_jacobians` and ``_record``
follow as the single env's do).
"""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import mujoco
import numpy as np

from cir_gym.envs.vector_base import BatchedTaskEnv, TaskStep
from cir_gym.envs.visual_servo import VisualServoEnv
from cir_gym.envs.visual_servo_base import CONVERGED, JOINT_MARGIN, MIN_DEPTH
from cir_gym.trajectories import skew
from cir_gym.vision import CAMERA_GEOM_GROUPS, camera_points, encloses, optical_pose

__all__ = ["VisualServoVectorEnv"]

_POSITION_STAGE = int(mujoco.mjtStage.mjSTAGE_POS)
#: model fields a copy's reset sets: the target's pose, the true camera's pose and intrinsics
_SCENE_FIELDS = ("body_pos", "body_quat", "cam_pos", "cam_quat", "cam_intrinsic")


class _GeomPoses(NamedTuple):
    """One copy's geom poses, read as an MjData's by ``cir_gym.vision.encloses``."""

    geom_xpos: np.ndarray  # (ngeom, 3)
    geom_xmat: np.ndarray  # (ngeom, 9)


class VisualServoVectorEnv(BatchedTaskEnv):
    """``num_envs`` copies of ``cir_gym/VisualServo-v1`` stepped by one ``mujoco.batch.Batch``;
    copy i of ``reset(seed=s)`` is the single env reset with s + i (module docstring).

    Args:
        num_envs: number of copies (≥ 1).
        nthread: MuJoCo threads (0: all CPUs).
        **kwargs: :class:`~cir_gym.envs.visual_servo.VisualServoEnv`'s arguments, except
            ``features="detected"``, ``obs_image=True`` and ``render_mode``.

    Raises:
        InvalidArgument: ``num_envs`` < 1, an unsupported argument, or one the single env
            rejects.
    """

    env_class: ClassVar[type[VisualServoEnv]] = VisualServoEnv
    env_id: ClassVar[str] = "cir_gym/VisualServo-v1"
    fixed_arguments: ClassVar[dict[str, Any]] = {"features": "projected", "obs_image": False}
    template: VisualServoEnv
    episode_state: ClassVar[tuple[str, ...]] = (
        "_s_ref",  # s* (4, 2) px
        "_s_true",  # the true camera's features (4, 2) px (the last seen ones)
        "_s_obs",  # the observed features (4, 2) px
        "_detect_failures",  # markers not found (0: projected features)
    )
    episode_history: ClassVar[tuple[str, ...]] = (
        "_err",  # true feature error (T + 1,) px
        "_pos",  # the moving frame's position in the goal frame (T + 1, 3) m
    )

    def _allocate(self) -> None:
        t, N, b = self.template, self.num_envs, self.batch
        m = t.model
        self._scene = {name: b.expand(name) for name in _SCENE_FIELDS}
        self._site_xpos = b.bind("site_xpos")  # (N, nsite, 3)
        self._site_xmat = b.bind("site_xmat")  # (N, nsite, 9)
        self._cam_xpos = b.bind("cam_xpos")  # (N, ncam, 3)
        self._cam_xmat = b.bind("cam_xmat")  # (N, ncam, 9)
        self._geom_xpos = b.bind("geom_xpos")  # (N, ngeom, 3)
        self._geom_xmat = b.bind("geom_xmat")  # (N, ngeom, 9)
        self._flange_body = int(m.site_bodyid[t._flange])
        self._servo_limit = m.actuator_ctrlrange[t.robot.actuator_ids, 1]  # (7,) > 0
        self._intrinsics = np.zeros((N, 4))  # the true camera's (f_u, f_v, c_u, c_v) px
        self._near = float(m.vis.map.znear * m.stat.extent)  # the renderer's near distance
        # geoms rigid with the camera: whether one encloses the camera centre holds for the
        # episode (1 / 0; −1: not tested yet); the others are tested at every step
        camera_weld = m.body_weldid[m.cam_bodyid[t._cam_id]]
        self._rigid = m.body_weldid[m.geom_bodyid] == camera_weld  # (ngeom,)
        self._encloses_camera = np.full((N, m.ngeom), -1, dtype=np.int8)
        self._feature_error = np.zeros(N)  # e (px) of every copy's last step

    def _start_episode(self, i: int) -> None:
        """Copy i's scene (target, true camera) from the template, its histories (the reset
        recorded step 0), and its poses."""
        t = self.template
        m = t.model
        self._err[i] = t._err
        self._pos[i] = t._pos
        for name, rows in self._scene.items():
            rows[i] = getattr(m, name)
        cam = t.true_camera
        self._intrinsics[i] = cam.fu, cam.fv, cam.cu, cam.cv
        self._encloses_camera[i] = -1
        self.batch.forward(ids=[i], stage=_POSITION_STAGE)

    # ------------------------------------------------------------------ step
    def _joint_command(self, a: np.ndarray) -> np.ndarray:
        """q̇ (N, 7) from the actions (N, m): a ⊙ q̇_max, or q̇ = J⁺ V for the twists
        V = a ⊙ twist limits in the twist's frame (:meth:`_twist_rotations`), J the moving
        frame's Jacobian at the copies' current joints (VisualServoBase._joint_command on
        rows)."""
        t = self.template
        if t.action_kind == "joint_velocity":
            return a * t.velocity_limit
        q = self._qpos[:, t.qpos_adr]
        R = self._twist_rotations()  # the twist's frame → world at q
        V = a * t.twist_limit
        V_world = np.concatenate((_rotate(R, V[:, :3]), _rotate(R, V[:, 3:])), axis=1)
        J = self._moving_jacobians()
        JT = np.swapaxes(J, 1, 2)
        try:
            qd = (JT @ np.linalg.solve(J @ JT, V_world[:, :, None]))[:, :, 0]  # J⁺ V
        except np.linalg.LinAlgError:  # a singular J Jᵀ: copy by copy
            qd = np.stack([_resolved_rate(J[i], V_world[i]) for i in range(self.num_envs)])
        corrupted = ~np.all(np.isfinite(q), axis=1)  # the physics step reports it
        qd[corrupted] = 0.0
        return qd

    def _twist_rotations(self) -> np.ndarray:
        """R (N, 3, 3): the twist's frame → world of every copy at its joints
        (VisualServoEnv._twist_rotation: the flange's, the camera's optical frame)."""
        return self._flange_rotations()

    def _flange_rotations(self) -> np.ndarray:
        """The flange's rotation (N, 3, 3), flange → world, at the batch's current poses."""
        return self._site_xmat[:, self.template._flange].reshape(-1, 3, 3)

    def _moving_jacobians(self) -> np.ndarray:
        """Geometric Jacobians (N, 6, 7) of the moving frame's origin, world frame, at the
        batch's current joints (VisualServoBase._moving_jacobian on rows): the flange's
        (``mj_jac`` at the flange site), its linear rows shifted to the point ``moving_offset``
        m along the flange's z axis, v_o = v_f − r × ω."""
        t = self.template
        jacp, jacr = self.batch.jac(self._flange_body, self._site_xpos[:, t._flange])
        # rows contiguous as the single env's J: its products round as there
        J = np.ascontiguousarray(np.concatenate((jacp, jacr), axis=1)[:, :, t.dof_adr])
        if t.moving_offset:
            r = t.moving_offset * self._flange_rotations()[:, :, 2]  # (N, 3) world
            J[:, :3] -= skew(r) @ J[:, 3:]
        return J

    def _servo_commands(self, qd: np.ndarray) -> np.ndarray:
        """Velocity-servo commands (N, nu): each row of q̇ (N, 7) scaled down uniformly
        (direction kept) to the actuators' ctrlrange (VisualServoBase._ctrl on rows)."""
        ratio = np.max(np.abs(qd) / self._servo_limit, axis=1)
        qd = qd / np.maximum(ratio, 1.0)[:, None]  # q̇ / 1 = q̇ exactly
        ctrl = np.zeros((self.num_envs, self.template.model.nu))
        ctrl[:, self.template.robot.actuator_ids] = qd
        return ctrl

    def _true_features(self) -> tuple[np.ndarray, np.ndarray]:
        """(s (N, 4, 2) px through each copy's true camera, behind (N,) bool: a marker at depth
        ≤ MIN_DEPTH, whose row of s is meaningless) at the batch's current poses."""
        t = self.template
        p_c, R_c = optical_pose(self._cam_xpos[:, t._cam_id], self._cam_xmat[:, t._cam_id])
        P = camera_points(self._geom_xpos[:, t._marker_ids], p_c, R_c)  # (N, 4, 3) optical
        Z = P[..., 2]
        behind = np.any(Z <= MIN_DEPTH, axis=1)
        fu, fv, cu, cv = (self._intrinsics[:, j, None] for j in range(4))
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.stack((cu + fu * P[..., 0] / Z, cv + fv * P[..., 1] / Z), axis=-1)
        return s, behind

    def _visible(self, ids: np.ndarray) -> np.ndarray:
        """(len(ids), 4) bool: the copies ``ids``'s true cameras see each marker's centre
        (:func:`cir_gym.vision.visible`'s rule, every copy's rays cast at once)."""
        t = self.template
        markers = t._marker_ids
        origin = self._cam_xpos[ids, t._cam_id]  # (n, 3)
        target = self._geom_xpos[ids][:, markers]  # (n, 4, 3)
        distance = np.linalg.norm(target - origin[:, None], axis=2)  # (n, 4)
        live = distance > self._near  # nearer than the near plane: not rendered
        direction = (target - origin[:, None]) / distance[..., None]
        start = origin[:, None] + self._near * direction
        seen = np.zeros(live.shape, dtype=bool)
        while live.any():
            ray = target - start  # x = 1 at the marker's centre
            x, hit = self.batch.ray(start, ray, geomgroup=CAMERA_GEOM_GROUPS, ids=ids)
            clear = live & ((x < 0.0) | (x >= 1.0) | (hit == markers))
            seen |= clear
            live &= ~clear
            r, j = np.nonzero(live)  # rays that met something else first
            if r.size:
                passes = self._encloses(ids[r], hit[r, j], origin[r], direction[r, j])
                start[r[passes], j[passes]] += (
                    x[r, j, None] * ray[r, j] + 1e-9 * direction[r, j]
                )[passes]  # on from beyond the enclosing geom's face
                live[r[~passes], j[~passes]] = False  # hidden
        return seen

    def _encloses(
        self, copies: np.ndarray, geoms: np.ndarray, origin: np.ndarray, direction: np.ndarray
    ) -> np.ndarray:
        """(n,) bool: whether geom ``geoms[r]`` encloses copy ``copies[r]``'s camera centre
        ``origin[r]`` (3,) (MuJoCo's ray test along ``direction[r]`` both ways); kept for the
        episode for a geom rigid with the camera."""
        known = self._encloses_camera[copies, geoms]  # (n,) 1 / 0, −1: to be tested
        for r in np.flatnonzero(known < 0):
            i, geom = int(copies[r]), int(geoms[r])
            poses = _GeomPoses(self._geom_xpos[i], self._geom_xmat[i])
            known[r] = encloses(self.template.model, poses, geom, origin[r], direction[r])
            if self._rigid[geom]:
                self._encloses_camera[i, geom] = known[r]
        return known > 0

    def _task_step(self, a: np.ndarray, peak: np.ndarray, k: np.ndarray) -> TaskStep:
        t, N = self.template, self.num_envs
        diverged = self._simulate(self._servo_commands(self._joint_command(a)))
        self.batch.forward(stage=_POSITION_STAGE)  # the flange, camera and marker poses
        q = self._qpos[:, t.qpos_adr]
        at_limit = np.any(q < t.lower + JOINT_MARGIN, axis=1) | np.any(
            q > t.upper - JOINT_MARGIN, axis=1
        )
        s, behind = self._true_features()
        measured = ~diverged & ~behind  # diverged or behind: the last seen features kept
        seen = np.zeros((N, 4), dtype=bool)
        ids = np.flatnonzero(measured)
        if ids.size:
            seen[ids] = self._visible(ids)
        in_view = np.all(t.nominal_camera.inside(s.reshape(-1, 2)).reshape(N, 4), axis=1)
        lost = ~measured | ~(in_view & np.all(seen, axis=1))
        self._s_true[measured] = s[measured]
        noise = np.stack([rng.standard_normal(8) for rng in self._rngs]).reshape(N, 4, 2)
        self._s_obs[:] = self._s_true + noise * t.pixel_noise
        e = self._record(self._k)
        terminated = diverged | lost | at_limit
        terms = t.reward_terms(e, a, terminated, t.max_steps - self._k)  # the single env's
        reward = terms["reward_features"] + terms["reward_action"] + terms["reward_termination"]
        self._feature_error = e
        infos = self._step_infos(
            {
                **terms,
                "feature_error": e,
                "feature_lost": lost,
                "features_visible": seen,
                "joint_limit": at_limit,
                "detection_failure": np.zeros(N, dtype=bool),
                "diverged": diverged,
            }
        )
        return self._observation(), reward, terminated, infos

    def error_norms(self) -> np.ndarray:
        """The true feature error e (N,) px of every copy's last step, the single env's
        ``info["feature_error"]`` (for training-only shaping, ``agents.batched``)."""
        return self._feature_error

    def _record(self, k: np.ndarray) -> np.ndarray:
        """Store and return the true feature error e (N,) px at steps k (N,), and the moving
        frame's position in the goal frame (VisualServoBase._record on rows)."""
        t, rows = self.template, self._rows
        d = (self._s_true - self._s_ref).reshape(self.num_envs, 8)
        e = np.sqrt(np.sum(d**2, axis=1) / 4)
        self._err[rows, k] = e
        p_g, R_g = t._goal_pose
        z = self._flange_rotations()[:, :, 2]
        p = self._site_xpos[:, t._flange] + t.moving_offset * z
        self._pos[rows, k] = (R_g.T @ (p - p_g)[:, :, None])[:, :, 0]  # R_gᵀ (p − p_g)
        return e

    def _observation(self) -> dict[str, np.ndarray]:
        """The observation of every copy (N, ...), clipped as the single env clips it."""
        t, N = self.template, self.num_envs
        bound = t._bound
        return {
            "features": np.clip(self._s_obs.reshape(N, 8), -bound, bound),
            "features_ref": np.clip(self._s_ref.reshape(N, 8), -bound, bound),
            "q": np.clip(self._qpos[:, t.qpos_adr], -2 * np.pi, 2 * np.pi),
        }

    def _episode_end(
        self, i: int, infos: dict[str, Any], terminated: bool, truncated: bool
    ) -> dict[str, Any]:
        """Metrics and success of copy ``i``: the template's, on the copy's history."""
        self._load_template(i)
        info = self._row_info(infos, i)
        metrics = self.template.episode_metrics()
        info["episode_metrics"] = metrics
        info["is_success"] = bool(not terminated and metrics["final_feature_error"] < CONVERGED)
        return info


def _rotate(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R v (N, m) for rows of matrices R (N, m, n) and vectors v (N, n)."""
    return (R @ v[:, :, None])[:, :, 0]


def _resolved_rate(J: np.ndarray, V: np.ndarray) -> np.ndarray:
    """J⁺ V (7,) of one copy: Jᵀ (J Jᵀ)⁻¹ V, or the least-squares solution where J Jᵀ is
    singular (VisualServoBase._joint_command)."""
    try:
        return J.T @ np.linalg.solve(J @ J.T, V)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(J, V, rcond=None)[0]
