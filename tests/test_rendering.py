"""cir_gym.rendering: visual-only markers, the caption font, and what the envs draw (issue 23).

Scene-level tests need no GL (an ``MjvScene`` is plain memory); frame-level tests render with
the headless backend cir_gym chose and are skipped when rendering is disabled. The cost of
rendering is measured by ``benchmarks/bench_render.py``, not asserted here.
"""

from __future__ import annotations

import os
import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import cir_gym
from cir_gym import rendering
from cir_gym.envs.base import GL_DISABLED
from cir_gym.robot import ROBOTS, Robot, load_model
from cir_gym.vision import Camera, optical_pose, project

needs_gl = pytest.mark.skipif(
    os.environ.get("MUJOCO_GL", "").strip().lower() in GL_DISABLED,
    reason="no GL backend (MUJOCO_GL disabled)",
)

#: every registered environment: each draws its task (issue 23)
ENV_IDS = sorted(cir_gym.ENVIRONMENTS)


def _scene(maxgeom: int = 100, robot: str = "planar3r") -> tuple[mujoco.MjvScene, Robot]:
    r = Robot.from_name(robot)
    return mujoco.MjvScene(r.model, maxgeom), r


# ---------------------------------------------------------------------- markers in a scene
def test_sphere_and_box_are_decoration_with_the_given_pose_and_colour() -> None:
    scene, _ = _scene()
    assert rendering.add_sphere(scene, [0.1, 0.2, 0.3], 0.05, (1, 0, 0, 0.5)) == 1
    R = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=float)
    assert rendering.add_box(scene, [1, 2, 3], [0.1, 0.2, 0.3], (0, 1, 0, 1), mat=R) == 1
    sphere, box = scene.geoms[0], scene.geoms[1]
    assert scene.ngeom == 2
    assert sphere.type == mujoco.mjtGeom.mjGEOM_SPHERE and box.type == mujoco.mjtGeom.mjGEOM_BOX
    assert sphere.category == mujoco.mjtCatBit.mjCAT_DECOR
    np.testing.assert_allclose(sphere.pos, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(sphere.size, [0.05] * 3)
    np.testing.assert_allclose(sphere.rgba, [1, 0, 0, 0.5])
    np.testing.assert_allclose(np.asarray(box.mat).reshape(3, 3), R)
    np.testing.assert_allclose(box.size, [0.1, 0.2, 0.3])


def test_capsule_spans_its_end_points() -> None:
    """A connector capsule: centre at the midpoint, half length |p1 − p0|/2, z axis along it."""
    scene, _ = _scene()
    p0, p1 = np.array([0.0, 0.0, 0.0]), np.array([0.3, 0.4, 0.0])
    rendering.add_capsule(scene, p0, p1, 0.01)
    g = scene.geoms[0]
    np.testing.assert_allclose(g.pos, (p0 + p1) / 2, atol=1e-6)
    np.testing.assert_allclose(g.size[[0, 2]], [0.01, 0.25], atol=1e-6)
    np.testing.assert_allclose(np.asarray(g.mat).reshape(3, 3)[:, 2], [0.6, 0.8, 0.0], atol=1e-6)


def test_arrow_points_along_its_vector_and_skips_a_zero_vector() -> None:
    scene, _ = _scene()
    assert rendering.add_arrow(scene, [1, 0, 0], [0, 0, 0.5], 0.01) == 1
    g = scene.geoms[0]
    assert g.type == mujoco.mjtGeom.mjGEOM_ARROW
    np.testing.assert_allclose(np.asarray(g.mat).reshape(3, 3)[:, 2], [0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(g.size[2], 0.5, atol=1e-6)  # arrow length
    assert rendering.add_arrow(scene, [0, 0, 0], [0, 0, 1e-6], 0.01) == 0
    assert rendering.add_arrow(scene, [0, 0, 0], [np.nan, 0, 1], 0.01) == 0
    assert scene.ngeom == 1


def test_frame_draws_the_columns_of_the_rotation_in_red_green_blue() -> None:
    scene, _ = _scene()
    c, s = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    p = np.array([0.2, -0.1, 0.5])
    assert rendering.add_frame(scene, p, R, 0.2) == 3
    for i, colour in enumerate((rendering.RED, rendering.GREEN, rendering.BLUE)):
        g = scene.geoms[i]
        np.testing.assert_allclose(g.pos, p + 0.1 * R[:, i], atol=1e-6)
        np.testing.assert_allclose(g.rgba, colour, atol=1e-6)


def test_polyline_is_subsampled_to_max_segments_keeping_its_ends() -> None:
    scene, _ = _scene(maxgeom=500)
    t = np.linspace(0, 2 * np.pi, 1001)
    pts = np.column_stack((np.cos(t), np.sin(t), np.zeros_like(t)))
    n = rendering.add_polyline(scene, pts, 0.01, max_segments=50)
    assert n == 50 == scene.ngeom
    ends = [np.asarray(scene.geoms[i].pos) for i in (0, n - 1)]
    # first segment starts at pts[0], last ends at pts[-1] (centres lie half a chord inside)
    assert np.linalg.norm(ends[0] - pts[0]) < 0.07 and np.linalg.norm(ends[1] - pts[-1]) < 0.07
    assert rendering.add_polyline(scene, pts[:1], 0.01) == 0
    scene.ngeom = 0
    assert rendering.add_polyline(scene, pts[:5], 0.0) == 4  # radius 0: GL lines
    assert scene.geoms[0].type == mujoco.mjtGeom.mjGEOM_LINE


def test_a_full_scene_drops_markers_instead_of_raising() -> None:
    scene, _ = _scene(maxgeom=3)
    added = rendering.add_polyline(scene, np.random.default_rng(0).normal(size=(20, 3)), 0.01)
    assert added == 3 == scene.ngeom
    assert rendering.add_sphere(scene, [0, 0, 0], 0.1) == 0
    assert rendering.add_frame(scene, [0, 0, 0], np.eye(3), 0.1) == 0
    assert scene.ngeom == 3


def test_ghost_copies_the_moving_geoms_at_the_given_pose_in_one_colour() -> None:
    scene, r = _scene(robot="iiwa14")
    data = mujoco.MjData(r.model)
    q = np.array([0.3, -0.5, 0.2, -1.2, 0.1, 0.8, -0.4])
    data.qpos[r.qpos_adr] = q
    mujoco.mj_kinematics(r.model, data)
    n = rendering.add_ghost(scene, r.model, data, (0, 1, 1, 0.3), inflate=1.0)
    # the arm's links beyond the base (geom group 0), not the payload box (group 1)
    moving = [
        g for g in range(r.model.ngeom) if r.model.geom_bodyid[g] > 1 and r.model.geom_group[g] == 0
    ]
    payload = mujoco.mj_name2id(r.model, mujoco.mjtObj.mjOBJ_GEOM, "payload_geom")
    assert payload >= 0 and payload not in moving
    assert n == len(moving) == scene.ngeom
    centres = np.array([scene.geoms[i].pos for i in range(n)])
    for g in moving:  # every moving geom has a copy at its pose for q
        assert np.min(np.linalg.norm(centres - data.geom_xpos[g], axis=1)) < 1e-6
    assert np.min(np.linalg.norm(centres - data.geom_xpos[payload], axis=1)) > 1e-3
    for i in range(n):
        np.testing.assert_allclose(scene.geoms[i].rgba, [0, 1, 1, 0.3], atol=1e-6)
        assert scene.geoms[i].category == mujoco.mjtCatBit.mjCAT_DECOR


def test_limit_colour_and_joint_margins() -> None:
    base = (0.2, 0.4, 0.6, 1.0)
    np.testing.assert_allclose(rendering.limit_colour(0.3, base), base, atol=1e-6)
    np.testing.assert_allclose(rendering.limit_colour(0.1, base), base, atol=1e-6)
    np.testing.assert_allclose(rendering.limit_colour(0.0, base), rendering.WARNING, atol=1e-6)
    half = rendering.limit_colour(0.05, base)
    np.testing.assert_allclose(
        half[:3], (np.array(base[:3]) + rendering.WARNING[:3]) / 2, atol=1e-6
    )
    m = rendering.joint_margins(np.array([0.0, 0.9, -1.0]), -np.ones(3), np.ones(3))
    np.testing.assert_allclose(m, [0.5, 0.05, 0.0])


def test_tint_joint_limits_recolours_only_the_link_behind_the_joint_at_its_limit() -> None:
    r = Robot.from_name("planar3r")
    scene = mujoco.MjvScene(r.model, 100)
    data = mujoco.MjData(r.model)
    q = np.array([0.0, r.upper[1] - 0.01, 0.0])  # joint 2 at 0.2 % of its range from the limit
    data.qpos[r.qpos_adr] = q
    mujoco.mj_forward(r.model, data)
    mujoco.mjv_updateScene(
        r.model,
        data,
        mujoco.MjvOption(),
        None,
        mujoco.MjvCamera(),
        int(mujoco.mjtCatBit.mjCAT_ALL),
        scene,
    )
    geoms = [scene.geoms[i] for i in range(scene.ngeom)]
    before = {(g.objtype, g.objid): np.array(g.rgba) for g in geoms}
    assert rendering.tint_joint_limits(scene, r.model, r.joint_ids, q, r.lower, r.upper) == 1
    link2 = mujoco.mj_name2id(r.model, mujoco.mjtObj.mjOBJ_GEOM, "link2_geom")
    for i in range(scene.ngeom):
        g = scene.geoms[i]
        if g.objtype == mujoco.mjtObj.mjOBJ_GEOM and g.objid == link2:
            assert g.rgba[0] > 0.9 and g.rgba[2] < 0.2  # red
        else:
            np.testing.assert_allclose(g.rgba, before[g.objtype, g.objid])


def test_place_world_geoms_uses_the_model_pose() -> None:
    """mj_kinematics leaves world geoms where they were compiled; the scene copy is moved."""
    spec = mujoco.MjSpec.from_file(str(cir_gym.robot.robot_path("planar3r")))
    spec.worldbody.add_geom(name="obstacle", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.05, 0, 0])
    model = spec.compile()
    data = mujoco.MjData(model)
    gid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "obstacle")
    model.geom_pos[gid] = [0.4, -0.2, 0.0]
    mujoco.mj_kinematics(model, data)
    scene = mujoco.MjvScene(model, 100)
    mujoco.mjv_updateScene(
        model,
        data,
        mujoco.MjvOption(),
        None,
        mujoco.MjvCamera(),
        int(mujoco.mjtCatBit.mjCAT_ALL),
        scene,
    )
    assert rendering.place_world_geoms(scene, model) >= 1
    obstacle = [
        scene.geoms[i]
        for i in range(scene.ngeom)
        if scene.geoms[i].objid == gid and scene.geoms[i].objtype == mujoco.mjtObj.mjOBJ_GEOM
    ]
    np.testing.assert_allclose(obstacle[0].pos, [0.4, -0.2, 0.0])


# ---------------------------------------------------------------------- caption font
def test_every_glyph_is_5_by_7_and_distinct() -> None:
    font = rendering._FONT
    assert {chr(c) for c in range(32, 127)} <= set(font)
    assert all(g.shape == (7, 5) for g in font.values())
    inked = {g.tobytes() for c, g in font.items() if c != " "}
    assert len(inked) == len(font) - 1  # no two characters look the same
    assert not font[" "].any()


def test_text_mask_size_combining_marks_and_unknown_characters() -> None:
    m = rendering.text_mask("t = 1.5 s", scale=2)
    assert m.shape == (14, 2 * 6 * 9) and m.dtype == bool
    np.testing.assert_array_equal(rendering.text_mask("q̄"), rendering.text_mask("q"))
    np.testing.assert_array_equal(rendering.text_mask("\u2603"), rendering.text_mask("?"))
    np.testing.assert_array_equal(rendering.text_mask("°")[:, :5], rendering._FONT["°"])


def test_draw_caption_writes_only_the_top_band_and_shrinks_to_fit() -> None:
    img = np.full((480, 480, 3), 100, dtype=np.uint8)
    out = rendering.draw_caption(img, "t = 1.00 s")
    assert out is img
    changed = np.any(img != 100, axis=2)
    rows = np.flatnonzero(changed.any(axis=1))
    assert rows.min() >= 0 and rows.max() < 4 + 7 * 2 + 2  # scale 2 at 480 px
    assert (img == 255).all(axis=2).sum() == rendering.text_mask("t = 1.00 s", 2).sum()
    small = np.full((100, 64, 3), 100, dtype=np.uint8)
    rendering.draw_caption(small, "a long caption that cannot fit in 64 px")  # clipped, no error
    assert np.any(small != 100)
    assert rendering.caption_scale(240) == 1 and rendering.caption_scale(480) == 2


# ---------------------------------------------------------------------- the robot files
@pytest.mark.parametrize("name", ROBOTS)
def test_floor_is_visual_only(name: str) -> None:
    model = load_model(name)
    floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    assert floor >= 0 and model.geom_type[floor] == mujoco.mjtGeom.mjGEOM_PLANE
    assert model.geom_contype[floor] == 0 and model.geom_conaffinity[floor] == 0
    assert model.geom_bodyid[floor] == 0


# ---------------------------------------------------------------------- rendered frames
def _frames(env: gym.Env) -> tuple[np.ndarray, np.ndarray]:
    """(with markers and caption, bare) frames of the same state."""
    u = env.unwrapped
    u.draw_markers = True
    full = env.render().copy()
    u.draw_markers = False
    bare = env.render().copy()
    u.draw_markers = True
    return full, bare


@needs_gl
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_frame_is_not_blank_and_the_task_changes_it(env_id: str) -> None:
    env = gym.make(env_id, render_mode="rgb_array", width=160, height=160)
    env.reset(seed=1)
    for _ in range(5):
        env.step(np.zeros(env.action_space.shape))
    full, bare = _frames(env)
    env.close()
    assert bare.shape == (160, 160, 3) and bare.dtype == np.uint8
    assert bare.std() > 10 and len(np.unique(bare.reshape(-1, 3), axis=0)) > 50  # floor + robot
    scene_diff = np.any(full[20:] != bare[20:], axis=2)  # below the caption band
    assert scene_diff.sum() >= 10, "draw_task added nothing visible"
    assert np.any(full[:20] != bare[:20]), "no caption"


@needs_gl
def test_a_marker_appears_where_the_camera_projects_it() -> None:
    """A sphere added in draw_task changes the pixels around its pinhole projection."""
    env = gym.make("cir_gym/RedundantIK-v4", render_mode="rgb_array", width=200, height=200)
    env.reset(seed=0)
    u = env.unwrapped
    point = np.array([0.7, 0.6, 0.05])  # inside the top camera's view, away from the arm

    def draw(scene: mujoco.MjvScene) -> None:
        rendering.add_sphere(scene, point, 0.03, (1.0, 0.0, 1.0, 1.0))

    u.caption = lambda: ""
    u.draw_task = lambda scene: None
    bare = env.render().copy()
    u.draw_task = draw
    marked = env.render().copy()
    env.close()
    cam = mujoco.mj_name2id(u.model, mujoco.mjtObj.mjOBJ_CAMERA, "top")
    p, R = optical_pose(u.data.cam_xpos[cam], u.data.cam_xmat[cam])
    uv = project((R.T @ (point - p))[None], Camera.from_model(u.model, cam, 200, 200))[0]
    changed = np.argwhere(np.any(marked != bare, axis=2))  # (row, col)
    assert len(changed) > 20
    centre = changed.mean(axis=0)[::-1]  # (u, v)
    assert np.linalg.norm(centre - uv) < 3.0, (centre, uv)


@needs_gl
def test_rendering_does_not_change_the_episode() -> None:
    """Markers are decoration: the same actions give the same observations with render()."""
    runs = []
    for mode in (None, "rgb_array"):
        env = gym.make("cir_gym/JointTracking-v2", render_mode=mode, width=64, height=64)
        obs, _ = env.reset(seed=4)
        rng = np.random.default_rng(0)
        trace = []
        for _ in range(20):
            obs, *_ = env.step(rng.uniform(-0.2, 0.2, env.action_space.shape))
            if mode:
                env.render()
            trace.append(np.concatenate([obs[k] for k in sorted(obs)]))
        env.close()
        runs.append(np.array(trace))
    np.testing.assert_array_equal(runs[0], runs[1])


@needs_gl
def test_sharp_floor_samples_the_floor_texture_nearest_and_changes_only_the_floor() -> None:
    """sharp_floor sets the floor texture's GL filters to GL_NEAREST once per renderer; the
    robot's pixels stay the same, the floor's checker stays two-tone-sharp (fewer colours)."""
    from OpenGL import GL

    model = load_model("iiwa14")
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    camera = mujoco.MjvCamera()
    mujoco.mjv_defaultFreeCamera(model, camera)
    with mujoco.Renderer(model, 120, 160) as renderer:
        renderer.update_scene(data, camera)
        trilinear = renderer.render().copy()
        renderer.update_scene(data, camera)
        floor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
        for i in range(renderer.scene.ngeom):  # the robot alone: the floor out of the scene
            if renderer.scene.geoms[i].objid == floor:
                renderer.scene.geoms[i].rgba[3] = 0.0
        robot = np.any(renderer.render() != 0, axis=2)
        texture = int(model.mat_texid[model.geom_matid[floor], mujoco.mjtTextureRole.mjTEXROLE_RGB])
        assert rendering.sharp_floor(renderer) == 1
        assert rendering.sharp_floor(renderer) == 0  # once per renderer
        renderer.update_scene(data, camera)
        nearest = renderer.render().copy()
        GL.glBindTexture(GL.GL_TEXTURE_2D, int(renderer._mjr_context.texture[texture]))
        filters = [
            GL.glGetTexParameteriv(GL.GL_TEXTURE_2D, p)
            for p in (GL.GL_TEXTURE_MIN_FILTER, GL.GL_TEXTURE_MAG_FILTER)
        ]
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
    assert [int(np.ravel(f)[0]) for f in filters] == [GL.GL_NEAREST, GL.GL_NEAREST]
    assert robot.sum() > 200 and np.array_equal(nearest[robot], trilinear[robot])
    changed = np.any(nearest != trilinear, axis=2)
    assert changed.sum() > 200 and not np.any(changed & robot)
    colours = [len(np.unique(f[~robot], axis=0)) for f in (trilinear, nearest)]
    assert colours[1] < colours[0], colours


def test_captions_report_the_primary_error_of_the_step() -> None:
    """JointTracking: ‖q̄ − q‖ of the last observation; RedundantIK: the step's task error."""
    env = gym.make("cir_gym/JointTracking-v2")
    env.reset(seed=2)
    for _ in range(10):
        obs, *_ = env.step(np.full(env.action_space.shape, 0.05))
    text = env.unwrapped.caption()
    err = np.linalg.norm(obs["q_ref"] - env.unwrapped.data.qpos[env.unwrapped.robot.qpos_adr])
    assert f"{err:.4f} rad" in text and text.startswith(f"t {10 * env.unwrapped.dt:5.2f} s")
    env.close()
    env = gym.make("cir_gym/RedundantIK-v4", objective="joint_limits")
    env.reset(seed=2)
    for _ in range(10):
        _, _, _, _, info = env.step(np.full(env.action_space.shape, 0.3))
    text = env.unwrapped.caption()
    assert f"e {1e3 * info['task_error']:5.2f} mm" in text
    assert f"margin {info['joint_limit_margin']:.3f} rad" in text
    env.close()


@needs_gl
@pytest.mark.parametrize("env_id", ["cir_gym/JointTracking-v2", "cir_gym/RedundantIK-v4"])
def test_overlay_projection_matches_the_rendered_scene(env_id: str) -> None:
    """project_points (the 2-D overlays' camera) puts a point where GL draws a sphere there,
    for the free camera (JointTracking) and a model camera (RedundantIK's "top")."""
    env = gym.make(env_id, render_mode="rgb_array", width=240, height=180)
    env.reset(seed=0)
    u = env.unwrapped
    u.caption = lambda: ""
    u.draw_task = lambda scene: None
    bare = env.render().copy()
    point = np.array([0.3, 0.55, 0.05])  # on the floor, clear of both arms

    def draw(scene: mujoco.MjvScene) -> None:
        rendering.add_sphere(scene, point, 0.035, (1.0, 0.0, 1.0, 1.0))

    u.draw_task = draw
    marked = env.render().copy()
    uv, depth = rendering.project_points(u._renderer.scene, point[None], 240, 180)
    env.close()
    changed = np.argwhere(np.any(marked != bare, axis=2))
    assert depth[0] > 0 and len(changed) > 10
    assert np.linalg.norm(changed.mean(axis=0)[::-1] - uv[0]) < 2.5, (changed.mean(0), uv)


def test_a_cached_overlay_draws_the_same_pixels_and_follows_the_camera() -> None:
    """finish_frame reuses a line's pixel mask only while the points, the camera and the
    frame size are the same: the cached frame equals a fresh one, and moving the camera
    redraws the line elsewhere."""
    model = load_model("planar3r")
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    scene = mujoco.MjvScene(model, maxgeom=100)
    cam = mujoco.MjvCamera()
    mujoco.mjv_defaultFreeCamera(model, cam)
    mujoco.mjv_updateScene(
        model, data, mujoco.MjvOption(), None, cam, int(mujoco.mjtCatBit.mjCAT_ALL), scene
    )
    path = np.column_stack(
        (
            0.4 * np.cos(np.linspace(0, 6.3, 200)),
            0.4 * np.sin(np.linspace(0, 6.3, 200)),
            np.zeros(200),
        )
    )

    def frame() -> np.ndarray:
        image = np.zeros((120, 160, 3), np.uint8)
        rendering.begin_frame(scene)
        rendering.add_polyline(scene, path, 0.004, (1.0, 0.0, 0.0, 1.0))
        return rendering.finish_frame(image, scene)

    rendering._MASKS.clear()
    fresh = frame()
    assert len(rendering._MASKS[id(scene)]) == 1 and fresh[..., 0].sum() > 0
    assert np.array_equal(frame(), fresh)  # from the cache
    cam.azimuth += 40.0
    mujoco.mjv_updateScene(
        model, data, mujoco.MjvOption(), None, cam, int(mujoco.mjtCatBit.mjCAT_ALL), scene
    )
    moved = frame()
    assert not np.array_equal(moved, fresh)
    rendering._MASKS.clear()
    assert np.array_equal(frame(), moved)  # the same as drawn without the cache


# ---------------------------------------------------------------------- videos and pacing
def _steps_to_end(env: gym.Env, render_each_step: bool = False) -> int:
    """Zero actions until the episode ends; the number of steps played."""
    steps = 0
    while True:
        _, _, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape))
        steps += 1
        if render_each_step:
            env.render()
        if terminated or truncated:
            return steps


@needs_gl
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_record_video_plays_in_real_time_at_most_60_fps(env_id: str, tmp_path) -> None:
    """gymnasium's RecordVideo on render_mode="rgb_array_list" writes an MP4 of at most 60 fps
    (it was 500 fps: the control rate) whose frames / fps is the episode's simulated duration
    within a frame."""
    pytest.importorskip("moviepy")
    ffmpeg = pytest.importorskip("imageio_ffmpeg")
    from gymnasium.wrappers import RecordVideo

    env = gym.make(env_id, render_mode="rgb_array_list", width=64, height=48,
                   episode_duration=0.4, max_episode_steps=-1)
    fps = env.metadata["render_fps"]
    assert 0 < fps <= 60
    env = RecordVideo(env, str(tmp_path / "videos"), episode_trigger=lambda episode: True,
                      name_prefix="video")
    env.reset(seed=0)
    with warnings.catch_warnings():  # RecordVideo's note on each step between two frames
        warnings.filterwarnings("ignore", ".*frame cannot be captured")
        steps = _steps_to_end(env)
    env.close()
    duration = steps * env.unwrapped.dt
    reader = ffmpeg.read_frames(str(tmp_path / "videos" / "video-episode-0.mp4"))
    meta = next(reader)
    frames = sum(1 for _ in reader)
    assert meta["fps"] == pytest.approx(fps, rel=1e-3)
    assert abs(frames / fps - duration) <= 1.0 / fps + 1e-9, (frames, fps, steps, duration)


@needs_gl
def test_rgb_array_list_draws_the_states_at_a_fixed_rate_of_simulated_time() -> None:
    """rgb_array_list: a frame at reset and every render_stride steps (50 fps at the 500-Hz
    control rate), each the rgb_array frame of the same state; render() hands each frame out
    once. rgb_array's render_fps is the control rate (one frame per step is real time)."""
    kwargs = {"width": 64, "height": 48, "episode_duration": 0.2}
    listed = gym.make("cir_gym/JointTracking-v2", render_mode="rgb_array_list", **kwargs)
    single = gym.make("cir_gym/JointTracking-v2", render_mode="rgb_array", **kwargs)
    u = listed.unwrapped
    assert (u.render_stride, listed.metadata["render_fps"]) == (10, 50)
    assert single.metadata["render_fps"] == round(1 / single.unwrapped.dt) == 500
    listed.reset(seed=3)
    single.reset(seed=3)
    expected, got = [single.render()], listed.render()
    rng = np.random.default_rng(0)
    for k in range(1, u.max_steps + 1):
        a = rng.uniform(-0.3, 0.3, listed.action_space.shape)
        listed.step(a)
        single.step(a)
        if k % 10 == 0:
            expected.append(single.render())
        if k % 7 == 0:  # any call pattern: the frames drawn since the last call
            got += listed.render()
    got += listed.render()
    assert listed.render() == []
    listed.close()
    single.close()
    assert len(got) == len(expected) == u.max_steps // 10 + 1
    for a, b in zip(got, expected, strict=True):
        np.testing.assert_array_equal(a, b)


class _StubViewer:
    """mujoco.viewer.launch_passive's handle, counting syncs (no window)."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.user_scn = mujoco.MjvScene(model, 1000)
        self.synced_at: list[float] = []

    def lock(self):
        import contextlib

        return contextlib.nullcontext()

    def sync(self) -> None:
        import time

        self.synced_at.append(time.perf_counter())

    def close(self) -> None:
        pass


def test_human_mode_shows_frames_at_render_fps_in_real_time(monkeypatch) -> None:
    """human: render() called every step syncs the viewer once per frame (render_fps of
    simulated time) and no faster than the wall clock: 0.3 s of episode take ≥ 0.3 s."""
    import sys
    import time

    from cir_gym.envs import base

    viewers: list[_StubViewer] = []

    def launch_passive(model: mujoco.MjModel, data: mujoco.MjData) -> _StubViewer:
        viewers.append(_StubViewer(model))
        return viewers[-1]

    fake = type(sys)("mujoco.viewer")
    fake.launch_passive = launch_passive  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "mujoco.viewer", fake)
    monkeypatch.setattr(mujoco, "viewer", fake, raising=False)
    monkeypatch.setattr(base, "_has_display", lambda: True)
    env = gym.make("cir_gym/JointTracking-v2", render_mode="human", episode_duration=0.3,
                   reference="regulation")  # at rest on a setpoint: no early stop
    fps = env.metadata["render_fps"]
    assert fps <= 60
    env.reset(seed=0)
    start = time.perf_counter()
    env.render()
    steps = _steps_to_end(env, render_each_step=True)
    elapsed = time.perf_counter() - start
    env.close()
    duration = steps * env.unwrapped.dt
    assert steps == env.unwrapped.max_steps
    assert len(viewers) == 1 and len(viewers[0].synced_at) == round(duration * fps) + 1
    assert elapsed >= duration - 1.5 / fps, (elapsed, duration)
