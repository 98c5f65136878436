"""Pictures of the task: visual-only markers for a ``mujoco.MjvScene`` and a caption on the frame.

Every function here appends *decoration* geoms (``mjCAT_DECOR``) to a scene after
``mjv_updateScene`` (``mujoco.Renderer.update_scene``) and before it is drawn: they are never in
the ``MjModel``, never collide and never change the physics. An environment draws its task in
:meth:`cir_gym.envs.base.RobotEnv.draw_task`::

    def draw_task(self, scene: mujoco.MjvScene) -> None:
        rendering.add_polyline(scene, self._path, 0.004, rendering.REFERENCE)
        rendering.add_frame(scene, self._x_ref[self._k], self._R_ref[self._k], 0.1)

Units: positions and lengths in metres (world frame), rotations as (3, 3) matrices whose columns
are the frame's axes in the world, colours as RGBA in [0, 1] (alpha < 1: translucent). Every
``add_*`` returns how many geoms it appended; when the scene is full (``scene.ngeom ==
scene.maxgeom``) the rest is dropped silently, so a marker never raises in the middle of a video
(``mujoco.Renderer`` makes room for ``max_geom`` = 10 000 geoms).

:func:`draw_caption` writes a caption (wrapped onto more lines when it is wider than the
frame) into an RGB frame (``mujoco.Renderer`` has no text
overlay) with a built-in 5 × 7 pixel font: ASCII plus ° ± × · Δ θ τ µ ≤ ≥ ω ‖ →; combining marks
(q̄) are dropped, any other character is drawn as "?".

Rendering cost: in software GL (llvmpipe) every geom is a draw call of ~0.1-0.3 ms at 320 px,
comparable to the whole bare robot, so a task should add a handful of geoms. Long lines
(paths, traces) therefore go through :func:`add_polyline`, which in a frame of
``RobotEnv.render`` (between :func:`begin_frame` and :func:`finish_frame`) is drawn into the
image as a 2-D overlay (on top of the scene, no occlusion) for ~0.3 ms whatever its length;
a line whose points, camera and frame size are those of the previous frame (a reference path
under a still camera) reuses its pixel mask, and only the blend is paid (~0.05 ms).
The checker floor fills most of a frame: trilinear texture filtering makes it cost about as
much as the bare robot, so :func:`sharp_floor` samples it nearest-texel (~0.6 ms less at
320 px). A translucent geom costs about twice an opaque one (the JointTracking ghost arm,
7 capsules: ~1 ms). ``benchmarks/bench_render.py`` measures the cost per frame against the
bare robot.

The second half of the module draws the shipped environments' tasks (their ``draw_task`` and
``caption`` call these), so that each env module keeps one short method.
"""

from __future__ import annotations

import itertools
import re
import unicodedata
import weakref
from typing import Any

import mujoco
import numpy as np

__all__ = [
    "BLUE",
    "GHOST",
    "GREEN",
    "OBSTACLE",
    "RED",
    "REFERENCE",
    "TARGET",
    "WARNING",
    "add_arrow",
    "add_box",
    "add_capsule",
    "add_frame",
    "add_ghost",
    "add_line",
    "add_polyline",
    "add_sphere",
    "begin_frame",
    "caption_scale",
    "draw_caption",
    "draw_joint_tracking",
    "draw_polyline_2d",
    "finish_frame",
    "joint_margins",
    "joint_tracking_caption",
    "limit_colour",
    "place_world_geoms",
    "project_points",
    "sharp_floor",
    "text_mask",
    "tint_bodies",
    "tint_joint_limits",
    "wrap_caption",
]

RED = (0.9, 0.15, 0.1, 1.0)
GREEN = (0.1, 0.8, 0.2, 1.0)
BLUE = (0.15, 0.35, 0.95, 1.0)
#: the reference (path, ghost arm): translucent cyan
REFERENCE = (0.1, 0.8, 0.95, 0.35)
#: a ghost arm at the reference pose: fainter than REFERENCE (it covers the arm); the
#: joint-space envs fade it further while the arm is on the reference
GHOST = (0.1, 0.8, 0.95, 0.22)
#: the target point / frame origin: opaque yellow
TARGET = (1.0, 0.85, 0.1, 1.0)
#: an obstacle: translucent red
OBSTACLE = (0.9, 0.1, 0.1, 0.55)
#: a warning (joint near its limit, contact): opaque red
WARNING = (1.0, 0.1, 0.05, 1.0)

_EYE = np.eye(3).ravel()
_DECOR = int(mujoco.mjtCatBit.mjCAT_DECOR)
_UNKNOWN = int(mujoco.mjtObj.mjOBJ_UNKNOWN)


# ---------------------------------------------------------------------------- geoms
def _next(scene: mujoco.MjvScene) -> Any:
    """The next free geom of ``scene`` (and count it), or None when the scene is full."""
    if scene.ngeom >= scene.maxgeom:
        return None
    geom = scene.geoms[scene.ngeom]
    scene.ngeom += 1
    return geom


def _vec3(value: Any) -> np.ndarray:
    return np.asarray(value, dtype=np.float64).reshape(3)


def _rgba(value: Any) -> np.ndarray:
    return np.asarray(value, dtype=np.float32).reshape(4)


def _decor(geom: Any) -> None:
    """Mark ``geom`` as decoration of no model object (mjv_initGeom leaves these fields as
    they were: a recycled scene slot would still name the geom it held last frame)."""
    geom.category = _DECOR
    geom.objtype = _UNKNOWN
    geom.objid = -1
    geom.segid = -1


def _init(geom: Any, rgba: Any) -> None:
    """mjv_initGeom with defaults (a decor sphere at the origin) and the colour."""
    mujoco.mjv_initGeom(
        geom, int(mujoco.mjtGeom.mjGEOM_SPHERE), np.zeros(3), np.zeros(3), _EYE, _rgba(rgba)
    )
    _decor(geom)


def add_sphere(scene: mujoco.MjvScene, pos: Any, radius: float, rgba: Any = TARGET) -> int:
    """A sphere at ``pos`` (3,) m of ``radius`` m."""
    geom = _next(scene)
    if geom is None:
        return 0
    mujoco.mjv_initGeom(
        geom,
        int(mujoco.mjtGeom.mjGEOM_SPHERE),
        np.full(3, float(radius)),
        _vec3(pos),
        _EYE,
        _rgba(rgba),
    )
    _decor(geom)
    return 1


def add_box(
    scene: mujoco.MjvScene, pos: Any, half_size: Any, rgba: Any = OBSTACLE, mat: Any = None
) -> int:
    """A box centred at ``pos`` (3,) m with half sizes ``half_size`` (3,) m, axes ``mat`` (3, 3)."""
    geom = _next(scene)
    if geom is None:
        return 0
    rot = _EYE if mat is None else np.asarray(mat, dtype=np.float64).reshape(9)
    mujoco.mjv_initGeom(
        geom, int(mujoco.mjtGeom.mjGEOM_BOX), _vec3(half_size), _vec3(pos), rot, _rgba(rgba)
    )
    _decor(geom)
    return 1


def _connector(scene: mujoco.MjvScene, kind: int, p0: Any, p1: Any, width: float, rgba: Any) -> int:
    a, b = _vec3(p0), _vec3(p1)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return 0
    geom = _next(scene)
    if geom is None:
        return 0
    _init(geom, rgba)
    mujoco.mjv_connector(geom, kind, float(width), a, b)
    return 1


def add_capsule(
    scene: mujoco.MjvScene, p0: Any, p1: Any, radius: float, rgba: Any = REFERENCE
) -> int:
    """A capsule (a thick line segment) from ``p0`` to ``p1`` (3,) m, ``radius`` m."""
    return _connector(scene, int(mujoco.mjtGeom.mjGEOM_CAPSULE), p0, p1, radius, rgba)


def add_line(
    scene: mujoco.MjvScene, p0: Any, p1: Any, width_px: float = 2.0, rgba: Any = REFERENCE
) -> int:
    """A GL line from ``p0`` to ``p1`` (3,) m, ``width_px`` pixels wide (cheapest marker)."""
    return _connector(scene, int(mujoco.mjtGeom.mjGEOM_LINE), p0, p1, width_px, rgba)


def add_arrow(
    scene: mujoco.MjvScene, start: Any, vector: Any, radius: float, rgba: Any = RED
) -> int:
    """An arrow from ``start`` (3,) m along ``vector`` (3,) m (its length is ``|vector|``).

    A vector shorter than ``radius`` draws nothing (an arrow has no direction then); scale
    forces to lengths before calling (e.g. 0.01 m per N).
    """
    v = _vec3(vector)
    if not np.all(np.isfinite(v)) or np.linalg.norm(v) < radius:
        return 0
    s = _vec3(start)
    return _connector(scene, int(mujoco.mjtGeom.mjGEOM_ARROW), s, s + v, radius, rgba)


def add_frame(
    scene: mujoco.MjvScene,
    pos: Any,
    mat: Any,
    length: float,
    radius: float | None = None,
    alpha: float = 1.0,
) -> int:
    """A coordinate frame: x, y, z axes (columns of ``mat`` (3, 3)) as red, green, blue capsules.

    Args:
        pos: (3,) origin (m).
        mat: (3, 3) rotation, columns = the frame's axes in the world.
        length: axis length (m).
        radius: axis radius (m); default ``length / 20``.
        alpha: opacity of the axes.
    """
    r = length / 20.0 if radius is None else radius
    p = _vec3(pos)
    R = np.asarray(mat, dtype=np.float64).reshape(3, 3)
    added = 0
    for i, colour in enumerate((RED, GREEN, BLUE)):
        added += add_capsule(scene, p, p + length * R[:, i], r, (*colour[:3], alpha))
    return added


def add_polyline(
    scene: mujoco.MjvScene,
    points: Any,
    radius: float,
    rgba: Any = REFERENCE,
    max_segments: int = 80,
) -> int:
    """A line through consecutive ``points`` (k, 3) m, about ``2 radius`` m thick.

    In a frame of :meth:`RobotEnv.render` (between :func:`begin_frame` and
    :func:`finish_frame`) the line is drawn into the image after the 3-D scene, as a 2-D
    overlay on top of it (no occlusion): a polyline costs ~1 ms however long (its pixels are
    kept for the next frame while it and the camera stay the same), where each
    capsule costs ~0.2 ms in software GL (each geom is a draw call). Elsewhere (the human
    viewer's scene, a bare ``MjvScene``) it is at most ``max_segments`` capsules (``radius ==
    0``: 2-pixel GL lines), subsampled evenly with both ends kept. Non-finite points break
    the line. Returns the number of segments.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) < 2:
        return 0
    pending = _OVERLAYS.get(id(scene))
    if pending is not None:
        pending.append((pts.copy(), float(radius), _rgba(rgba)))
        return len(pts) - 1
    if len(pts) - 1 > max_segments:
        idx = np.unique(np.linspace(0, len(pts) - 1, max_segments + 1).round().astype(int))
        pts = pts[idx]
    added = 0
    for a, b in itertools.pairwise(pts):
        if radius > 0:
            added += add_capsule(scene, a, b, radius, rgba)
        else:
            added += add_line(scene, a, b, 2.0, rgba)
    return added


# ---------------------------------------------------------------------------- 2-D overlays
#: widest overlay line (px): wider costs one array pass per pixel of the pen's disc
MAX_LINE_PX = 5.0
#: polylines waiting for the rendered image, per scene (id) between begin and finish_frame
_OVERLAYS: dict[int, list[tuple[np.ndarray, float, np.ndarray]]] = {}


def begin_frame(scene: mujoco.MjvScene) -> None:
    """Start collecting :func:`add_polyline` lines of ``scene`` as 2-D overlays."""
    _OVERLAYS[id(scene)] = []


def finish_frame(frame: np.ndarray, scene: mujoco.MjvScene, caption: str = "") -> np.ndarray:
    """Draw the overlays collected since :func:`begin_frame` and the caption into ``frame``.

    ``frame`` (h, w, 3) uint8, rows top first (``mujoco.Renderer.render``), is what
    ``scene`` (after ``update_scene``, whose camera is used) was rendered to. In place.
    """
    overlays = _OVERLAYS.pop(id(scene), [])
    if overlays:
        camera = _camera_key(scene, frame.shape)
        previous = _MASKS.get(id(scene), {})
        current: dict[bytes, _Mask | None] = {}
        for pts, radius, rgba in overlays:
            key = camera + np.float64(radius).tobytes() + pts.tobytes()
            if key in previous:  # same line, camera and frame size: the same pixels
                mask = previous[key]
            else:
                mask = _overlay_mask(scene, pts, radius, frame.shape)
            current[key] = mask
            if mask is not None:
                _blend(frame, mask, rgba)
        if len(_MASKS) >= _MAX_CACHED_SCENES and id(scene) not in _MASKS:
            _MASKS.clear()  # scenes come and go (one per renderer): forget the old ones
        _MASKS[id(scene)] = current  # only this frame's lines are kept
    return draw_caption(frame, caption)


#: (y0, x0, mask): the pixels of a 2-D line, a boolean mask of the crop at (y0, x0)
_Mask = tuple[int, int, np.ndarray]
#: the last frame's line masks per scene (id), keyed by camera, frame size, radius and points:
#: a static line (a reference path) seen by a still camera is rasterised once
_MASKS: dict[int, dict[bytes, _Mask | None]] = {}
_MAX_CACHED_SCENES = 32


def _camera_key(scene: mujoco.MjvScene, shape: tuple[int, ...]) -> bytes:
    """Everything of ``scene``'s camera and the frame size a projected line depends on."""
    c0, c1 = scene.camera[0], scene.camera[1]
    values = [
        *c0.pos,
        *c0.forward,
        *c0.up,
        *c1.pos,
        *c1.forward,
        *c1.up,
        c0.frustum_bottom,
        c0.frustum_top,
        c0.frustum_near,
        c0.frustum_center,
        *shape[:2],
    ]
    return np.array(values, dtype=np.float64).tobytes()


def _overlay_mask(
    scene: mujoco.MjvScene, pts: np.ndarray, radius: float, shape: tuple[int, ...]
) -> _Mask | None:
    """The pixels of the 2-D line through world ``pts`` (k, 3), ``2 radius`` m thick at the
    line's median depth (1.5 to ``MAX_LINE_PX`` px), in a frame of ``shape`` of ``scene``."""
    uv, depth = project_points(scene, pts, shape[1], shape[0])
    _, _, bottom, top, near, _, _ = _frustum(scene)
    focal = shape[0] * near / max(top - bottom, 1e-12)  # px
    front = depth[depth > 0]
    width = 2.0 * radius * focal / float(np.median(front)) if len(front) else 2.0
    return _line_mask(uv, float(np.clip(width, 1.5, MAX_LINE_PX)), shape[0], shape[1])


def _frustum(
    scene: mujoco.MjvScene,
) -> tuple[np.ndarray, np.ndarray, float, float, float, np.ndarray, float]:
    """(pos, forward, bottom, top, near, up, centre) of the scene's mono camera (the mean of
    the two GL cameras, as mjr_render draws)."""
    c0, c1 = scene.camera[0], scene.camera[1]
    pos = (np.asarray(c0.pos) + np.asarray(c1.pos)) / 2
    fwd = (np.asarray(c0.forward) + np.asarray(c1.forward)) / 2
    up = (np.asarray(c0.up) + np.asarray(c1.up)) / 2
    return (
        pos,
        fwd / np.linalg.norm(fwd),
        float(c0.frustum_bottom),
        float(c0.frustum_top),
        float(c0.frustum_near),
        up / np.linalg.norm(up),
        float(c0.frustum_center),
    )


def project_points(
    scene: mujoco.MjvScene, points: Any, width: int, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (k, 2) (u right, v down, pixel centres at integers) and depths (k,) m
    of world ``points`` (k, 3) in a ``width`` × ``height`` frame of ``scene``'s camera.

    Perspective cameras only. A point at or behind the camera has depth ≤ 0 and uv NaN.
    """
    pos, fwd, bottom, top, near, up, centre = _frustum(scene)
    right = np.cross(fwd, up)
    d = np.asarray(points, dtype=np.float64).reshape(-1, 3) - pos
    z = d @ fwd
    half_w = 0.5 * (top - bottom) * width / height
    with np.errstate(divide="ignore", invalid="ignore"):
        xn = (d @ right) * near / z
        yn = (d @ up) * near / z
        u = (xn - (centre - half_w)) / (2 * half_w) * width - 0.5
        v = (top - yn) / (top - bottom) * height - 0.5
    uv = np.column_stack((u, v))
    uv[z <= 0] = np.nan
    return uv, z


def draw_polyline_2d(image: np.ndarray, uv: np.ndarray, width: float, rgba: Any) -> np.ndarray:
    """Blend a polyline through pixel points ``uv`` (k, 2) into ``image`` (h, w, 3), in place.

    Segments with a NaN end are skipped; ``width`` in px; alpha ``rgba[3]``.
    """
    mask = _line_mask(np.asarray(uv, dtype=np.float64), width, *image.shape[:2])
    if mask is not None:
        _blend(image, mask, rgba)
    return image


def _line_mask(uv: np.ndarray, width: float, h: int, w: int) -> _Mask | None:
    """:func:`draw_polyline_2d`'s pixels in an h × w image (None: none inside)."""
    a, b = uv[:-1], uv[1:]
    ok = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    a, b = a[ok], b[ok]
    if len(a) == 0:
        return None
    lengths = np.linalg.norm(b - a, axis=1)
    counts = np.minimum(np.ceil(lengths).astype(int) + 1, 2 * (h + w))  # ~1 px steps
    seg = np.repeat(np.arange(len(a)), counts)
    start = np.repeat(np.cumsum(counts) - counts, counts)
    t = (np.arange(len(seg)) - start) / np.maximum(np.repeat(counts, counts) - 1, 1)
    samples = np.rint(a[seg] + t[:, None] * (b - a)[seg]).astype(np.int64)
    keep = (
        (samples[:, 0] >= -8)
        & (samples[:, 0] < w + 8)
        & (samples[:, 1] >= -8)
        & (samples[:, 1] < h + 8)
    )
    samples = samples[keep]
    r = max(width / 2.0, 0.5)
    k = int(np.ceil(r))
    inside = (samples[:, 0] >= 0) & (samples[:, 0] < w) & (samples[:, 1] >= 0) & (samples[:, 1] < h)
    samples = samples[inside]
    if len(samples) == 0:
        return None
    # the line's bounding box, grown by the pen's radius: the dilation works on that crop
    x0, y0 = np.maximum(samples.min(axis=0) - k, 0)
    x1, y1 = np.minimum(samples.max(axis=0) + k + 1, (w, h))
    bw, bh = x1 - x0, y1 - y0
    centres = np.zeros((bh + 2 * k, bw + 2 * k), dtype=bool)  # padded by the pen's radius
    centres[samples[:, 1] - y0 + k, samples[:, 0] - x0 + k] = True
    mask = np.zeros((bh, bw), dtype=bool)
    for dy in range(-k, k + 1):  # dilate the centre line by a disc: one slice per offset
        for dx in range(-k, k + 1):
            if dx * dx + dy * dy <= r * r + 0.25:
                mask |= centres[k + dy : k + dy + bh, k + dx : k + dx + bw]
    return int(y0), int(x0), mask


def _blend(image: np.ndarray, line: _Mask, rgba: Any) -> None:
    """Blend colour ``rgba`` (alpha ``rgba[3]``) into ``image`` where ``line`` is set."""
    y0, x0, mask = line
    crop = image[y0 : y0 + mask.shape[0], x0 : x0 + mask.shape[1]]  # a view into the frame
    colour = _rgba(rgba)
    alpha = float(colour[3])
    pixels = crop[mask]
    blended = (1.0 - alpha) * pixels[:, :3] + alpha * 255.0 * colour[:3]
    crop[mask, :3] = np.clip(blended, 0, 255).astype(image.dtype)


def add_ghost(
    scene: mujoco.MjvScene,
    model: mujoco.MjModel,
    data: mujoco.MjData,
    rgba: Any = REFERENCE,
    option: mujoco.MjvOption | None = None,
    inflate: float = 1.03,
) -> int:
    """A translucent copy of the robot's moving geoms at the pose held in ``data``.

    ``data`` is a second ``MjData`` of ``model`` (not the simulation's) on which the caller ran
    ``mj_kinematics`` at the pose to show (e.g. the reference q̄). Its moving geoms are appended
    in colour ``rgba`` as decoration; primitive sizes are scaled by ``inflate`` so that the
    ghost does not flicker against the arm when they coincide.
    """
    start = scene.ngeom
    mujoco.mjv_addGeoms(
        model,
        data,
        option or _default_option(),
        _default_perturb(),
        int(mujoco.mjtCatBit.mjCAT_DYNAMIC),
        scene,
    )
    colour = _rgba(rgba)
    mesh = int(mujoco.mjtGeom.mjGEOM_MESH)
    for i in range(start, scene.ngeom):
        geom = scene.geoms[i]
        geom.rgba[:] = colour
        _decor(geom)
        geom.objtype = int(mujoco.mjtObj.mjOBJ_UNKNOWN)
        geom.objid = -1
        geom.segid = -1
        geom.matid = -1
        geom.emission = 0.2
        if geom.type != mesh:
            geom.size[:] = np.asarray(geom.size) * inflate
    return scene.ngeom - start


_OPTION: mujoco.MjvOption | None = None
_PERTURB: mujoco.MjvPerturb | None = None


def _default_option() -> mujoco.MjvOption:
    global _OPTION
    if _OPTION is None:
        _OPTION = mujoco.MjvOption()
        _OPTION.sitegroup[:] = 0  # the ghost shows geoms only,
        _OPTION.geomgroup[1:] = 0  # the robot's (group 0): not a payload or a visual extra
    return _OPTION


def _default_perturb() -> mujoco.MjvPerturb:
    global _PERTURB
    if _PERTURB is None:
        _PERTURB = mujoco.MjvPerturb()
    return _PERTURB


def limit_colour(margin: float, base: Any, warn_below: float = 0.1) -> np.ndarray:
    """``base`` RGBA blended toward :data:`WARNING` as a joint nears its limit.

    Args:
        margin: distance to the nearest limit as a fraction of the range, in [0, 0.5].
        base: the joint's normal colour.
        warn_below: margins at or above it keep ``base``; at 0 the colour is :data:`WARNING`.
    """
    w = float(np.clip(1.0 - margin / warn_below, 0.0, 1.0)) if warn_below > 0 else 0.0
    b = _rgba(base)
    out = (1.0 - w) * b + w * _rgba(WARNING)
    out[3] = max(b[3], w)
    return out


# ---------------------------------------------------------------------------- GL state
#: renderers whose floor texture is already sampled nearest-texel
_SHARP_FLOORS: weakref.WeakSet[Any] = weakref.WeakSet()


def sharp_floor(renderer: mujoco.Renderer) -> int:
    """Sample the floor's texture nearest-texel, without mipmaps, in ``renderer``'s GL context.

    MuJoCo uploads 2-D textures with trilinear (mipmapped) filtering. In software GL (llvmpipe)
    the checker floor, which fills most of a frame, then costs ~1 ms of a 320-px frame, about
    as much as the bare robot (``benchmarks/bench_render.py``); sampled nearest-texel it costs
    ~0.4 ms and stays a checker (hard square edges; far squares alias a little). Changes the
    textures of the materials of the model's plane geoms, once per renderer (a second call
    returns 0). Only how this renderer draws changes, never the model. Any GL failure (no
    PyOpenGL, no current context) leaves the filtering as it was and returns 0; otherwise
    returns the number of textures changed.
    """
    if renderer in _SHARP_FLOORS:
        return 0
    _SHARP_FLOORS.add(renderer)
    model = getattr(renderer, "model", None)
    context = getattr(renderer, "_mjr_context", None)  # no public accessor (mujoco 4.0.0)
    if model is None or context is None:
        return 0
    plane = int(mujoco.mjtGeom.mjGEOM_PLANE)
    rgb = int(mujoco.mjtTextureRole.mjTEXROLE_RGB)
    tex2d = int(mujoco.mjtTexture.mjTEXTURE_2D)
    texids = {
        int(model.mat_texid[m, rgb])
        for m in model.geom_matid[model.geom_type == plane]
        if m >= 0 and model.mat_texid[m, rgb] >= 0
    }
    names = [int(context.texture[t]) for t in texids if context.textureType[t] == tex2d]
    if not names:
        return 0
    try:
        from OpenGL import GL  # PyOpenGL: a dependency of mujoco (its EGL/OSMesa backends)

        gl_context = getattr(renderer, "_gl_context", None)
        if gl_context is not None:
            gl_context.make_current()
        for name in names:
            GL.glBindTexture(GL.GL_TEXTURE_2D, name)
            GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MIN_FILTER, GL.GL_NEAREST)
            GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAG_FILTER, GL.GL_NEAREST)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
    except Exception:  # an optimisation only: the frame is right either way
        return 0
    return len(names)


# ---------------------------------------------------------------------------- caption
# 5 × 7 glyphs, written for cir_gym: each glyph is its character followed by 7 rows, top to
# bottom, one base-32 digit per row (bit 4 = leftmost pixel).
_GLYPHS = (
    " 0000000!4444404\"aa00000#aavavaa$4fke5u4%op248j3&cik8lid'4400000(2488842)8422248"
    "*04lel40+044v440,0000c48-000v000.00000cc/01248g00ehjlphe14c4444e2eh1248v3v2421he"
    "426aiv225vgu11he668guhhe7v1248888ehhehhe9ehhf12c:0cc0cc0;0cc0c48<248g842=00v0v00"
    ">8421248?eh12404@eh1dlleAehhvhhhBuhhuhhuCehgggheDsihhhisEvgguggvFvggugggGehgnhhf"
    "HhhhvhhhIe44444eJ72222icKhikokihLggggggvMhrllhhhNhhpljhhOehhhhhePuhhugggQehhhlid"
    "RuhhukihSfgge11uTv444444UhhhhhheVhhhhha4WhhhlllaXhha4ahhYhha4444Zv1248gv[e88888e"
    "\\0g84210]e22222e^4ah0000_000000v`8400000a00e1fhfbggmphhuc00egghed11djhhfe00ehvge"
    "f698s888g0fhhf1ehggmphhhi40c444ej20622ickggikokilc44444em00qllhhn00mphhho00ehhhe"
    "p00uhuggq00djf11r00mpgggs00ege1ut88s8896u00hhhjdv00hhha4w00hhllax00ha4ahy00hhf1e"
    "z00v248v{2448442|4444444}8442448~008l200°ciic000±44v440v×0ha4ah0·0004000Δ044aahv"
    "θehhvhheτ00v4442µ00hhjtg≤248420f≥842480uω00ahlla‖aaaaaaa→042v240"
)
GLYPH_W, GLYPH_H = 5, 7


def _decode_glyphs() -> dict[str, np.ndarray]:
    bits = 1 << np.arange(GLYPH_W - 1, -1, -1)
    font = {}
    for i in range(0, len(_GLYPHS), 1 + GLYPH_H):
        rows = np.array([int(c, 32) for c in _GLYPHS[i + 1 : i + 1 + GLYPH_H]])
        font[_GLYPHS[i]] = (rows[:, None] & bits) > 0
    return font


_FONT = _decode_glyphs()
_INDEX = {c: i for i, c in enumerate(_FONT)}
_ATLAS = np.zeros((len(_FONT), GLYPH_H, GLYPH_W + 1), dtype=bool)
for _c, _i in _INDEX.items():
    _ATLAS[_i, :, :GLYPH_W] = _FONT[_c]


def _printable(text: str) -> str:
    """Drop combining marks (q̄ → q); replace characters the font lacks by "?"."""
    if text.isascii() and text.isprintable():
        return text
    decomposed = unicodedata.normalize("NFD", text)
    chars = (c for c in decomposed if not unicodedata.combining(c))
    return "".join(c if c in _FONT else "?" for c in chars)


def text_mask(text: str, scale: int = 1) -> np.ndarray:
    """Boolean ink mask (7 s, 6 s · len) of one line of ``text`` at integer ``scale`` s."""
    line = _printable(text.replace("\n", " "))
    if not line:
        return np.zeros((GLYPH_H * scale, 0), dtype=bool)
    glyphs = _ATLAS[[_INDEX[c] for c in line]]  # (L, 7, 6): each glyph and a blank column
    mask = glyphs.transpose(1, 0, 2).reshape(GLYPH_H, -1)
    if scale > 1:
        mask = mask.repeat(scale, axis=0).repeat(scale, axis=1)
    return mask


def caption_scale(height: int) -> int:
    """Font scale for a frame ``height`` px tall: 1 below 300 px, then one more per 240 px."""
    return max(1, 1 + (int(height) - 60) // 240)


def wrap_caption(text: str, width: int, scale: int) -> list[str]:
    """``text`` broken into lines of at most ``width`` px at ``scale``: between fields first
    (two or more spaces before a word that is not a number: ``"t  0.62 s  depth  -0.07 mm"``
    has the fields ``t  0.62 s`` and ``depth  -0.07 mm``), then between words; a word longer
    than a line is cut where it overflows."""
    chars = max(1, width // ((GLYPH_W + 1) * scale))
    line = " ".join(text.split("\n"))
    if len(_printable(line)) <= chars:
        return [line]
    lines: list[str] = []
    current = ""
    for field in (f.strip() for f in re.split(r" {2,}(?=[^\d\s+\-.])", line) if f.strip()):
        joined = f"{current}  {field}" if current else field
        if len(_printable(joined)) <= chars:
            current = joined
            continue
        if current:
            lines.append(current)
        current = ""
        for word in field.split():
            joined = f"{current} {word}" if current else word
            if len(_printable(joined)) <= chars:
                current = joined
                continue
            if current:
                lines.append(current)
            while len(_printable(word)) > chars:  # a word wider than the line: cut it
                lines.append(word[:chars])
                word = word[chars:]
            current = word
    if current:
        lines.append(current)
    return lines


def draw_caption(
    image: np.ndarray,
    text: str,
    scale: int | None = None,
    colour: tuple[int, int, int] = (255, 255, 255),
    background: float = 0.55,
    margin: int = 4,
    max_lines: int = 3,
) -> np.ndarray:
    """Write ``text`` at the top-left of ``image`` (h, w, 3) uint8, in place; return ``image``.

    The text sits on a dark band (the pixels under it are multiplied by ``1 - background``).
    ``scale`` defaults to :func:`caption_scale`; a caption wider than the frame is wrapped
    (:func:`wrap_caption`) onto at most ``max_lines`` lines, the default scale reduced (down
    to 1) until it fits them; at scale 1 (or a given ``scale``) it takes the lines it needs.
    """
    if not text:
        return image
    h, w = image.shape[:2]
    s = caption_scale(h) if scale is None else max(1, int(scale))
    lines = wrap_caption(text, w - 2 * margin, s)
    while scale is None and s > 1 and len(lines) > max_lines:
        s -= 1  # the default scale shrinks until the caption fits its lines
        lines = wrap_caption(text, w - 2 * margin, s)
    pad, step = s, (GLYPH_H + 3) * s
    y0 = x0 = margin
    keep = round(256 * (1.0 - background))
    for i, line in enumerate(lines):
        mask = text_mask(line, s)
        y = y0 + i * step
        mh = min(mask.shape[0], h - y)
        mw = min(mask.shape[1], w - x0)
        if mh <= 0 or mw <= 0:
            break
        top = max(0, y - pad) if i == 0 else y - 2 * s  # the bands of two lines join
        band = image[top : y + mh + pad, max(0, x0 - pad) : x0 + mw + pad]
        band[:] = ((band.astype(np.uint16) * keep) >> 8).astype(image.dtype)
        region = image[y : y + mh, x0 : x0 + mw]
        region[mask[:mh, :mw]] = colour
    return image


# ---------------------------------------------------------------------------- task pictures
def tint_bodies(scene: mujoco.MjvScene, model: mujoco.MjModel, colours: dict[int, Any]) -> int:
    """Recolour the model geoms already in ``scene`` that belong to the bodies in ``colours``.

    ``colours`` maps a body id to an RGBA. Only the scene's copy changes (``model.geom_rgba``
    does not); returns the number of geoms recoloured.
    """
    if not colours:
        return 0
    kind = int(mujoco.mjtObj.mjOBJ_GEOM)
    changed = 0
    for i in range(scene.ngeom):
        geom = scene.geoms[i]
        if geom.objtype != kind or geom.objid < 0:
            continue
        rgba = colours.get(int(model.geom_bodyid[geom.objid]))
        if rgba is not None:
            geom.rgba[:] = _rgba(rgba)
            changed += 1
    return changed


def place_world_geoms(scene: mujoco.MjvScene, model: mujoco.MjModel) -> int:
    """Put the scene's copies of world-body geoms at ``model.geom_pos``/``geom_quat``.

    ``mj_kinematics`` does not recompute the poses of geoms on the world body, so a world geom
    moved at run time through ``model.geom_pos`` (an obstacle placed per episode) is drawn
    where it was compiled. Returns the number of geoms placed.
    """
    kind = int(mujoco.mjtObj.mjOBJ_GEOM)
    mat = np.empty(9)
    placed = 0
    for i in range(scene.ngeom):
        geom = scene.geoms[i]
        if geom.objtype != kind or geom.objid < 0 or model.geom_bodyid[geom.objid] != 0:
            continue
        geom.pos[:] = model.geom_pos[geom.objid]
        mujoco.mju_quat2Mat(mat, model.geom_quat[geom.objid])
        geom.mat[:] = mat.reshape(3, 3)
        placed += 1
    return placed


def joint_margins(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Distance of each joint to its nearest limit as a fraction of its range, (n,) in [0, 0.5]."""
    span = np.maximum(np.asarray(upper) - np.asarray(lower), 1e-12)
    return np.clip(np.minimum(q - lower, upper - q) / span, 0.0, 0.5)


def tint_joint_limits(
    scene: mujoco.MjvScene,
    model: mujoco.MjModel,
    joint_ids: np.ndarray,
    q: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    warn_below: float = 0.1,
) -> int:
    """Colour each link toward red as its joint (``joint_ids``, (n,)) nears a limit.

    A link whose joint is at least ``warn_below`` of its range from both limits keeps its
    colour; see :func:`limit_colour`.
    """
    margins = joint_margins(q, lower, upper)
    colours = {}
    for j, m in zip(joint_ids, margins, strict=True):
        if m < warn_below:
            body = int(model.jnt_bodyid[j])
            base = model.geom_rgba[model.geom_bodyid == body]
            colours[body] = limit_colour(float(m), base[0] if len(base) else WARNING, warn_below)
    return tint_bodies(scene, model, colours)


class _Ghost:
    """A second MjData of a model, for drawing poses other than the simulated one."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.key: tuple[Any, ...] = ()
        self.trace = np.zeros((0, 3))

    def pose(self, qpos: np.ndarray, adr: np.ndarray, q: np.ndarray) -> mujoco.MjData:
        self.data.qpos[:] = qpos
        self.data.qpos[adr] = q
        mujoco.mj_kinematics(self.model, self.data)
        return self.data

    def site_path(self, qpos: np.ndarray, adr: np.ndarray, qs: np.ndarray, site: int) -> np.ndarray:
        """World positions (k, 3) of ``site`` along the joint path ``qs`` (k, n)."""
        out = np.empty((len(qs), 3))
        for i, q in enumerate(qs):
            out[i] = self.pose(qpos, adr, q).site_xpos[site]
        return out


_GHOSTS: weakref.WeakKeyDictionary[Any, _Ghost] = weakref.WeakKeyDictionary()


def _ghost(env: Any) -> _Ghost:
    ghost = _GHOSTS.get(env)
    if ghost is None or ghost.model is not env.model:
        ghost = _GHOSTS[env] = _Ghost(env.model)
    return ghost


def _site(model: mujoco.MjModel, names: tuple[str, ...]) -> int:
    for name in names:
        i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name)
        if i >= 0:
            return i
    return -1


#: samples of a reference drawn as a polyline
TRACE_SAMPLES = 120


def draw_joint_tracking(env: Any, scene: mujoco.MjvScene) -> None:
    """JointTracking(-like) task: a translucent ghost arm at q̄(t) and the flange's reference path.

    Reads ``env.model``, ``env.data``, ``env.robot.qpos_adr``, ``env._ref`` (3, K+1, n) and
    ``env._k``; the flange path (site ``flange``, else ``ee``) is computed once per episode.
    """
    ghost = _ghost(env)
    adr = env.robot.qpos_adr
    ref = env._ref[0]
    k = min(env._k, len(ref) - 1)
    site = _site(env.model, ("flange", "ee", "tcp"))
    if site >= 0:
        key = (ref[0].tobytes(), ref[-1].tobytes(), ref[len(ref) // 2].tobytes())
        if key != ghost.key:
            idx = np.unique(np.linspace(0, len(ref) - 1, TRACE_SAMPLES).round().astype(int))
            ghost.trace = ghost.site_path(env.data.qpos, adr, ref[idx], site)
            ghost.key = key
        add_polyline(scene, ghost.trace, 0.006, REFERENCE, max_segments=TRACE_SAMPLES)
    data = ghost.pose(env.data.qpos, adr, ref[k])
    # faint while the arm is on the reference (it would hide the arm), clearer as they part
    err = float(np.linalg.norm(ref[k] - env.data.qpos[adr]))
    add_ghost(scene, env.model, data, (*GHOST[:3], 0.06 + 0.24 * min(1.0, err / 0.1)))
    if site >= 0:
        add_sphere(scene, data.site_xpos[site], 0.02, TARGET)
        add_sphere(scene, env.data.site_xpos[site], 0.015, GREEN)


def joint_tracking_caption(env: Any) -> str:
    """``t``, the joint error ‖q̄ − q‖ now and its RMS so far (rad)."""
    k = min(env._k, env.max_steps)
    q = env.data.qpos[env.robot.qpos_adr]
    err = float(np.linalg.norm(env._ref[0, k] - q))
    rms = float(np.sqrt(np.mean(env._err[:k] ** 2))) if k > 0 else 0.0
    return f"t {k * env.dt:5.2f} s  |q_ref-q| {err:.4f} rad  rms {rms:.4f}"


def _as_3d(points: np.ndarray, z: float = 0.0) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.shape[-1] == 3:
        return pts
    return np.concatenate((pts, np.full((*pts.shape[:-1], 3 - pts.shape[-1]), z)), axis=-1)

