"""VisualServo-v1's batched env against the single env, copy by copy (course controller and
random actions over whole episodes, a start that loses a feature, the calibration error, the
rotation family, joint-velocity actions), its line of sight, autoreset, make_vec and the
batched evaluator (gymnasium.make_vec's equivalence is tested with the others in
test_vector.py).

Tolerance: observations, rewards, step infos and episode metrics to 1e-12 relative, the
equivalence this env states. The batch runs MuJoCo's own computations of the single env
(mj_step; the position stage for the flange, camera and marker poses; mj_jac at the flange as
mj_jacSite; mj_ray through ``Batch.ray``) and the single env's arithmetic on (N, ...) rows laid
out as its arrays, so today it is even bit for bit (measured); the tolerance leaves numpy room
to reduce an (N, 8) array in another order than an (8,) row.
"""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from lockstep import assert_same_episodes, episode_ends, noisy_actions, only_copy_ends

import cir_gym
from cir_gym import baselines, vision
from cir_gym.envs.vector import VECTOR_ENVS
from cir_gym.envs.visual_servo import VisualServoEnv
from cir_gym.envs.visual_servo_eye_to_hand_vector import VisualServoEyeToHandVectorEnv
from cir_gym.envs.visual_servo_vector import VisualServoVectorEnv
from cir_gym.evaluation import evaluate
from cir_gym.validation import InvalidArgument

ENV = "cir_gym/VisualServo-v1"
TOL = 1e-12
ROTATIONS = (0.3, np.pi)  # the rotation family: spin about the optical axis up to 180°
#: a start 0.35 m to the side: its features sit near the image's left edge (margin 0 for a
#: given start), and turning about the camera's y axis at full speed loses one at step 4
EDGE_START = (0.35, 0.0, 0.0, 0.0, 0.0, 0.0)
TURN = np.array([0.0, 0.0, 0.0, 0.0, 1.0, 0.0], dtype=np.float32)


def _ibvs_with_noise(std: float, seed: int = 0):
    """IBVS plus Gaussian noise on each copy (tests/lockstep.py noisy_actions)."""
    return noisy_actions(baselines.make("ibvs", ENV), std, seed)


def _run(kw: dict, act, steps: int, n: int = 3, seed: int = 5) -> list[dict]:
    """The single envs' last infos of the episodes that ended in a lockstep of ``n`` copies."""
    return episode_ends(VisualServoVectorEnv, VisualServoEnv, kw, act, steps, TOL, n, seed)


@pytest.mark.parametrize(
    "kw, std",
    [
        # the leaderboard's calibration-error variant, 1-s episodes: truncations, autoresets
        ({"episode_duration": 1.0, "camera_error": (0.05, 10.0, 0.01, 0.02)}, 0.2),
        # the rotation family under large noise: features lost at different steps
        ({"episode_duration": 2.0, "start_rotation": ROTATIONS}, 1.5),
    ],
    ids=["calibration_error", "rotation_family"],
)
def test_each_copy_is_the_single_env_under_ibvs_with_noise(kw, std):
    ends = _run(kw, _ibvs_with_noise(std), steps=75)
    assert len(ends) >= 3  # every copy crossed an episode end (1-s / 2-s episodes: 25 / 50 steps)
    if std > 1.0:
        assert any(info["feature_lost"] for info in ends)


def test_a_start_that_loses_a_feature_terminates_as_the_single_env():
    """Copy 0 turns at full speed from the edge start and loses a feature at step 4, again and
    again (its start is fixed); copy 1 turns the other way and is truncated; copy 2 is driven
    by IBVS. Ends, the termination charge and the final metrics are the single env's."""
    kw = {"start_offset": EDGE_START, "episode_duration": 0.4}  # 10 steps
    policy = baselines.make("ibvs", ENV)

    def act(k: int, obs: dict, start: np.ndarray) -> np.ndarray:
        a = policy.predict(obs)[0]
        a[0], a[1] = TURN, -TURN
        return a

    ends = _run(kw, act, steps=25)
    lost = [info for info in ends if info["feature_lost"]]
    assert len(lost) >= 5 and len(ends) > len(lost)
    assert all(info["reward_termination"] < -50.0 for info in lost)
    assert all(not info["is_success"] for info in lost)


def test_joint_velocity_actions_without_noise():
    kw = {"action": "joint_velocity", "episode_duration": 0.6, "pixel_noise": 0.0}
    actions = np.random.default_rng(2).uniform(-1.2, 1.2, (40, 3, 7)).astype(np.float32)
    ends = _run(kw, lambda k, obs, start: actions[k], steps=len(actions))
    assert len(ends) >= 3


@pytest.mark.parametrize(
    ("vec_cls", "kw"),
    [(VisualServoVectorEnv, {}),
     (VisualServoEyeToHandVectorEnv, {"camera_error": (0.05, 10.0, 0.01, 0.02)})],
    ids=["eye_in_hand", "eye_to_hand"],
)
def test_the_line_of_sight_is_the_single_envs_rule_in_any_configuration(vec_cls, kw):
    """Random joint configurations (eye in hand: the camera looking anywhere, through links,
    at the plate's back; eye to hand: the plate anywhere, turned away, behind the arm): each
    copy's visibility of the four markers is cir_gym.vision.visible's on the template in the
    same state."""
    envs = vec_cls(num_envs=1, nthread=1, **kw)
    envs.reset(seed=3)  # the template holds copy 0's scene
    t = envs.template
    rng = np.random.default_rng(0)
    counts = np.zeros(2, dtype=int)
    for _ in range(60):
        q = rng.uniform(t.lower + 0.1, t.upper - 0.1)
        envs._qpos[0, t.qpos_adr] = q
        envs.batch.forward(stage=1)
        t._set_state(q)
        want = t._visible()
        np.testing.assert_array_equal(envs._visible(np.array([0]))[0], want)
        counts += np.bincount(want.astype(int), minlength=2)
    assert counts.min() >= 10  # both outcomes, many times
    envs.close()


def test_markers_behind_their_plate_are_hidden_and_lost_as_in_the_single_env():
    """Copy 0's target turned its back to the camera (π about its x axis, in copy 0's own
    model row and in the single env's model): the markers stay in the image but the plate
    hides them, so the step loses them; copy 1 (unchanged) sees them all."""
    envs = VisualServoVectorEnv(num_envs=2, nthread=1)
    single = VisualServoEnv()
    envs.reset(seed=3)
    single.reset(seed=3)
    target = single.model.body("target").id
    flipped = np.zeros(4)
    mujoco.mju_mulQuat(flipped, single.model.body_quat[target], np.array([0.0, 1.0, 0.0, 0.0]))
    single.model.body_quat[target] = flipped
    envs.batch.expand("body_quat")[0, target] = flipped
    a = np.zeros((2, 6), dtype=np.float32)
    _, rew, term, _, infos = envs.step(a)
    _, w_rew, w_term, _, w_info = single.step(a[0])
    assert w_term and w_info["feature_lost"] and not w_info["features_visible"].any()
    assert list(term) == [True, False] and rew[0] == pytest.approx(w_rew, rel=TOL)
    assert infos["features_visible"].tolist() == [[False] * 4, [True] * 4]
    assert infos["final_info"]["feature_lost"][0]
    envs.close()


def test_autoreset_keeps_each_copys_scene_and_generator():
    """Copy 1 alone terminates (the edge start turned): its final observation is under the
    masks, its row is the next episode's start (the same generator: the single env's next
    reset), the other copies go on; each copy keeps its own target pose and camera."""
    kw = {"start_offset": EDGE_START, "episode_duration": 0.4,
          "camera_error": (0.05, 10.0, 0.01, 0.02)}
    envs = VisualServoVectorEnv(num_envs=3, nthread=1, **kw)
    single = VisualServoEnv(**kw)
    obs, infos = envs.reset(seed=[4, 9, 5])
    np.testing.assert_allclose(obs["features"][1], single.reset(seed=9)[0]["features"], rtol=TOL)
    cams = envs._intrinsics.copy()
    assert len({tuple(c) for c in cams}) == 3  # three calibration errors
    a = np.zeros((3, 6), dtype=np.float32)
    a[1] = TURN
    infos, w_info = only_copy_ends(envs, single, a, 1, TOL)
    assert w_info["feature_lost"]
    assert list(infos["_start_offset"]) == [False, True, False]
    np.testing.assert_array_equal(envs._intrinsics[[0, 2]], cams[[0, 2]])
    t = single
    assert envs._intrinsics[1].tolist() == [t.true_camera.fu, t.true_camera.fv,
                                            t.true_camera.cu, t.true_camera.cv]
    envs.close()


#: both visual-servoing ids: their batched env and the IBVS law of each
BATCHED_VS = [(ENV, VisualServoVectorEnv, "ibvs"),
              ("cir_gym/VisualServoEyeToHand-v1", VisualServoEyeToHandVectorEnv,
               "ibvs_eye_to_hand")]


@pytest.mark.parametrize(("env_id", "vec_cls", "law"), BATCHED_VS, ids=["eye_in_hand",
                                                                         "eye_to_hand"])
def test_make_vec_builds_it_and_falls_back_on_rendered_features(env_id, vec_cls, law):
    assert VECTOR_ENVS[env_id] is vec_cls
    native = cir_gym.make_vec(env_id, 2, nthread=1, episode_duration=0.2)
    assert type(native) is vec_cls
    native.close()
    for kwargs in ({"features": "detected"}, {"obs_image": True}):
        name = next(iter(kwargs))
        with pytest.raises(InvalidArgument, match=name):
            vec_cls(num_envs=2, **kwargs)
        sync = cir_gym.make_vec(env_id, 2, **kwargs)
        assert isinstance(sync, gym.vector.SyncVectorEnv), name
        sync.close()
    with pytest.raises(InvalidArgument, match="pixel_noise"):
        vec_cls(num_envs=2, pixel_noise=-1.0)


@pytest.mark.parametrize(("env_id", "vec_cls", "law"), BATCHED_VS, ids=["eye_in_hand",
                                                                         "eye_to_hand"])
def test_batched_evaluation_gives_the_sequential_episodes(env_id, vec_cls, law):
    """evaluate()'s batched path (the id is in BATCHED_ENVIRONMENTS, the IBVS law runs on
    rows) on the rotation family: IBVS fails some starts there (a lost feature, a joint limit);
    every EpisodeResult is the sequential one."""
    policy = baselines.make(law, env_id)
    kw = {"start_rotation": ROTATIONS, "episode_duration": 2.0}
    batched = evaluate(policy, env_id, 4, seed=1000, **kw)
    sequential = evaluate(policy, env_id, 4, seed=1000, batched=False, **kw)
    assert [e.terminated for e in sequential.episodes].count(True) >= 1
    assert_same_episodes(batched, sequential, TOL)


def test_the_projection_rows_are_cir_gym_visions():
    """The features the batch computes for a copy are cir_gym.vision's projection of the
    markers through the copy's true camera (the template's after its reset)."""
    envs = VisualServoVectorEnv(num_envs=1, nthread=1, camera_error=(0.05, 10.0, 0.01, 0.02))
    envs.reset(seed=8)
    t = envs.template
    s, behind = envs._true_features()
    assert not behind[0]
    np.testing.assert_allclose(s[0], t._true_features(), rtol=TOL)
    d, cid = t.data, t._cam_id
    p_c, R_c = vision.optical_pose(d.cam_xpos[cid], d.cam_xmat[cid])
    P = vision.camera_points(d.geom_xpos[t._marker_ids], p_c, R_c)
    np.testing.assert_allclose(s[0], vision.project(P, t.true_camera), rtol=0, atol=1e-9)
    envs.close()
