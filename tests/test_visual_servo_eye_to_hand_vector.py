"""VisualServoEyeToHand-v1's batched env against the single env, copy by copy (the course
controller with noise and random actions over whole episodes, starts that lose a feature out
of the image and behind the turning plate, the calibration error, the rotation family,
joint-velocity actions), its line of sight, autoreset; and ``ibvs_eye_to_hand`` on rows.

Tolerance: observations, rewards, step infos and episode metrics to 1e-12 relative, the
equivalence this env states (as VisualServo-v1's, tests/test_visual_servo_vector.py: the batch
runs MuJoCo's computations of the single env and its arithmetic on (N, ...) rows; measured bit
for bit today). The law: a row of a batch against the same observation alone bit for bit, and
against the law written out here with cir_gym.vision's single-case functions to 1e-12 of the
largest command (measured: bit for bit).
"""

from __future__ import annotations

import numpy as np
import pytest
from lockstep import (
    SB3_RTOL,
    episode_ends,
    noisy_actions,
    only_copy_ends,
    row,
    sampled_observations,
    sb3_step,
)

from cir_gym import baselines, vision
from cir_gym.envs.visual_servo_eye_to_hand import VisualServoEyeToHandEnv
from cir_gym.envs.visual_servo_eye_to_hand_vector import VisualServoEyeToHandVectorEnv
from cir_gym.trajectories import skew

ENV = "cir_gym/VisualServoEyeToHand-v1"
TOL = 1e-12
ROTATIONS = (0.3, np.pi)  # the rotation family: spin about the plate's normal up to 180°
CALIBRATION = (0.05, 10.0, 0.01, 0.02)  # the leaderboard's calibration-error variant
#: the plate 0.3 m below its goal: its markers near the image's bottom edge; moving it down
#: (+y of the camera) at full speed takes one out of the image at step 5
LOW_START = (0.0, 0.3, 0.0, 0.0, 0.0, 0.0)
DOWN = np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0], dtype=np.float32)
#: the plate 0.3 m to the side: turning it about the camera's y axis at full speed, its own
#: plate hides two markers still inside the image at step 34
SIDE_START = (0.3, 0.0, 0.0, 0.0, 0.0, 0.0)
TURN = np.array([0.0, 0.0, 0.0, 0.0, 1.0, 0.0], dtype=np.float32)


def _ibvs(env_kwargs: dict, **gains):
    return baselines.make("ibvs_eye_to_hand", ENV, env_kwargs=env_kwargs, **gains)


def _ibvs_with_noise(std: float, kw: dict, seed: int = 0):
    """IBVS (of ``kw``'s action) plus Gaussian noise on each copy (tests/lockstep.py)."""
    return noisy_actions(_ibvs({k: v for k, v in kw.items() if k == "action"}), std, seed)


def _run(kw: dict, act, steps: int, n: int = 3, seed: int = 5) -> list[dict]:
    """The single envs' last infos of the episodes that ended in a lockstep of ``n`` copies."""
    return episode_ends(VisualServoEyeToHandVectorEnv, VisualServoEyeToHandEnv, kw, act, steps,
                        TOL, n, seed)


@pytest.mark.parametrize(
    "kw, std",
    [
        # 1-s episodes of the calibration-error variant: truncations, autoresets
        ({"episode_duration": 1.0, "camera_error": CALIBRATION}, 0.2),
        # the rotation family under large noise: joint limits at different steps
        ({"episode_duration": 2.0, "start_rotation": ROTATIONS}, 1.5),
        # joint velocities through the plate's image Jacobian
        ({"episode_duration": 0.6, "action": "joint_velocity", "camera_error": CALIBRATION},
         0.5),
    ],
    ids=["calibration_error", "rotation_family", "joint_velocity"],
)
def test_each_copy_is_the_single_env_under_ibvs_with_noise(kw, std):
    ends = _run(kw, _ibvs_with_noise(std, kw), steps=75 if std < 1.0 else 60)
    assert len(ends) >= 3  # every copy crossed an episode end
    if std > 1.0:
        assert any(info["joint_limit"] for info in ends)


@pytest.mark.parametrize(
    "start, duration, move, steps, hidden",
    [
        (LOW_START, 0.4, DOWN, 25, False),  # out of the image at step 5, episode after episode
        (SIDE_START, 1.6, TURN, 36, True),  # behind its own plate at step 34, inside the image
    ],
    ids=["out_of_the_image", "behind_the_plate"],
)
def test_a_start_that_loses_a_feature_terminates_as_the_single_env(start, duration, move,
                                                                     steps, hidden):
    """Copy 0 moves (turns) the plate at full speed from a fixed start and loses a feature;
    copy 1 moves it the other way, copy 2 is driven by IBVS. Ends, the termination charge,
    the line of sight and the final metrics are the single env's."""
    kw = {"start_offset": start, "episode_duration": duration}
    policy = _ibvs({})

    def act(k: int, obs: dict, start: np.ndarray) -> np.ndarray:
        a = policy.predict(obs)[0]
        a[0], a[1] = move, -move
        return a

    lost = [info for info in _run(kw, act, steps=steps) if info["feature_lost"]]
    assert len(lost) >= (1 if hidden else 5)
    assert all(info["reward_termination"] < -50.0 and not info["is_success"] for info in lost)
    seen = [int(info["features_visible"].sum()) for info in lost]
    assert all(0 < n < 4 for n in seen) if hidden else all(n == 4 for n in seen)


def test_random_joint_velocities_without_noise():
    kw = {"action": "joint_velocity", "episode_duration": 0.6, "pixel_noise": 0.0}
    actions = np.random.default_rng(2).uniform(-1.2, 1.2, (40, 3, 7)).astype(np.float32)
    ends = _run(kw, lambda k, obs, start: actions[k], steps=len(actions))
    assert len(ends) >= 3


def test_autoreset_keeps_each_copys_camera_and_generator():
    """Copy 1 alone terminates (the low start moved down): its final observation is under the
    masks, its row is the next episode's start (the same generator: the single env's next
    reset), the other copies go on; each copy keeps its own true camera (pose, intrinsics)."""
    kw = {"start_offset": LOW_START, "episode_duration": 0.4, "camera_error": CALIBRATION}
    envs = VisualServoEyeToHandVectorEnv(num_envs=3, nthread=1, **kw)
    single = VisualServoEyeToHandEnv(**kw)
    obs, _ = envs.reset(seed=[4, 9, 5])
    np.testing.assert_allclose(obs["features"][1], single.reset(seed=9)[0]["features"], rtol=TOL)
    poses = envs._scene["cam_pos"][:, single._cam_id].copy()
    assert len({tuple(p) for p in poses}) == 3  # three extrinsic errors
    a = np.zeros((3, 6), dtype=np.float32)
    a[1] = DOWN
    _, w_info = only_copy_ends(envs, single, a, 1, TOL)
    assert w_info["feature_lost"]
    after = envs._scene["cam_pos"][:, single._cam_id]
    np.testing.assert_array_equal(after[[0, 2]], poses[[0, 2]])
    np.testing.assert_array_equal(after[1], single.model.cam_pos[single._cam_id])
    c = single.true_camera
    assert envs._intrinsics[1].tolist() == [c.fu, c.fv, c.cu, c.cv]
    envs.close()


# make_vec, the line of sight and the batched evaluate of this env:
# tests/test_visual_servo_vector.py (parametrized over both visual-servoing ids)


def test_a_residual_over_ibvs_is_the_single_residual_stack():
    """vec_env 'batched' for a residual agent (agents.batched: BatchedResidualAction with the
    row-law IBVS once per vector step, the log-error bonus on the env's error_norms) against
    the single stack of agents.train.EnvFactory, three copies with random agent actions
    through terminations and truncations (SB3's float32 values to 1e-6, as
    tests/test_residual_batched_vs.py)."""
    pytest.importorskip("stable_baselines3")
    from cir_gym.agents.batched import make_batched_vec_env
    from cir_gym.agents.observation import ObservationLayout
    from cir_gym.agents.train import EnvFactory

    kwargs = {"start_rotation": ROTATIONS, "episode_duration": 2.0}
    log_error = {"weight": 0.1, "max_error": 100.0, "floor": 0.01}
    gains = {"gain": 0.6058598995030436}  # tuned:ibvs_eye_to_hand
    probe = VisualServoEyeToHandEnv(**kwargs)
    layout = ObservationLayout.from_space(probe.observation_space)
    probe.close()
    n, seed = 3, 10
    venv = make_batched_vec_env(ENV, kwargs, layout, n, seed, log_error=log_error,
                                residual="ibvs_eye_to_hand", scale=0.25,
                                controller_kwargs=gains)
    singles = [EnvFactory(ENV, kwargs, layout, "ibvs_eye_to_hand", 0.25, gains,
                          log_error=log_error)() for _ in range(n)]
    obs = venv.reset()
    for i, env in enumerate(singles):
        np.testing.assert_allclose(obs[i], env.reset(seed=seed + i)[0], rtol=SB3_RTOL,
                                   atol=SB3_RTOL)
    rng = np.random.default_rng(0)
    ends = []
    for k in range(60):
        ends += sb3_step(venv, singles, rng.uniform(-1, 1, (n, 6)).astype(np.float32), k)
    venv.close()
    assert {i for i, _ in ends} == {0, 1, 2}


# ---------------------------------------------------------------------- the law on rows
#: (gains, env arguments): every branch (where L̂ is evaluated, the adaptive gain, the
#: pseudo-inverse, the joint-velocity action through the nominal robot)
LAWS = [
    ({}, {}),
    ({"depth": "mean"}, {}),
    ({"depth": "desired", "adaptive": (4.0, 0.4, 30.0)}, {}),
    ({"damping": 0.0}, {}),
    ({}, {"action": "joint_velocity"}),
    ({"depth": "mean", "adaptive": (4.0, 0.4, 30.0)}, {"action": "joint_velocity"}),
]


@pytest.fixture(scope="module")
def servo_obs() -> dict[str, np.ndarray]:
    """96 observations of the rotation family with a calibration error: IBVS plus noise on
    16 batched copies (features anywhere in the image, rotations up to 180°), every 4th step."""
    envs = VisualServoEyeToHandVectorEnv(num_envs=16, nthread=1, start_rotation=ROTATIONS,
                                         camera_error=CALIBRATION, pixel_noise=0.5)
    return sampled_observations(envs, _ibvs({}))


def _course_command(policy, obs: dict[str, np.ndarray]) -> np.ndarray:
    """The course's eye-to-hand IBVS on one observation with cir_gym.vision's single-case
    functions (baselines/visual_servo.py's module docstring): V_m = −λ (L̂ G)* e, or
    q̇ = −λ (L̂ G M J)* e, scaled down uniformly to its limits."""
    cam, P, g = policy.camera, policy.model_points, policy.gains
    s, s_ref = obs["features"].reshape(4, 2), obs["features_ref"].reshape(4, 2)

    def interaction(x: np.ndarray) -> np.ndarray:
        R, t = vision.planar_pose(P, x, cam)
        Z = np.maximum(vision.transform_points(R, t, P)[:, 2], 1e-3)
        G = np.zeros((6, 6))
        G[:3, :3], G[:3, 3:], G[3:, 3:] = -np.eye(3), -skew(t), -np.eye(3)
        return vision.interaction_matrix(x, Z, cam) @ G

    at = {"current": [s], "desired": [s_ref], "mean": [s, s_ref]}[g.depth]
    A = sum(interaction(x) for x in at) / len(at)
    size = float(np.max(np.abs(vision.normalise(s, cam) - vision.normalise(s_ref, cam))))
    lam = g.gain if g.adaptive is None else baselines.visual_servo.adaptive_gain(
        size, *g.adaptive)
    limit = policy.twist_limit
    if policy.context.action_kind == "joint_velocity":
        R_f = policy.robot.site_pose(policy.site, obs["q"])[1]
        J = policy.robot.jacobian(policy.site, obs["q"])
        Rc = policy.camera_rotation
        M = np.zeros((6, 6))
        M[:3, :3], M[3:, 3:] = Rc.T, Rc.T
        M[:3, 3:] = -Rc.T @ skew(policy.moving_offset * R_f[:, 2])
        A, limit = A @ M @ J, policy.velocity_limit
    command = -lam * vision.damped_pinv(A, g.damping) @ (s - s_ref).ravel()
    ratio = float(np.max(np.abs(command) / limit))
    return command / ratio if ratio > 1.0 else command


@pytest.mark.parametrize("gains, env_kwargs", LAWS)
def test_the_law_on_rows_is_each_row_alone_and_the_course_law(gains, env_kwargs, servo_obs):
    policy = _ibvs(env_kwargs, **gains)
    assert policy.vectorized
    n = len(servo_obs["q"])
    state = np.zeros((n, 0))
    alone = np.stack([policy.control(row(servo_obs, i), state[i]) for i in range(n)])
    rng = np.random.default_rng(1)
    for count in (1, 3, n):  # batches of any size, rows reordered
        pick = rng.permutation(n)[:count]
        rows = {key: v[pick] for key, v in servo_obs.items()}
        np.testing.assert_array_equal(policy.control_batch(rows, state[pick]), alone[pick])
    want = np.stack([_course_command(policy, row(servo_obs, i)) for i in range(n)])
    scale = np.max(np.abs(want), axis=1, keepdims=True)
    assert np.max(np.abs(alone - want) / scale) <= TOL
    assert np.ptp(want[:, 0]) > 0.1 * np.max(np.abs(want[:, 0]))  # the rows differ
