"""Vision science for visual servoing (chapter 7): pinhole camera, point features, pose,
the interaction matrix and its damped inverse, line of sight, colour-marker detection.

Conventions (stated once, used everywhere):

* **Optical frame** (the textbook's and OpenCV's): origin at the optical centre, z along the
  optical axis (forward, points in front have Z > 0), x to the right of the image, y *down*
  the image. Every point, pose and twist in this module is in an optical frame.
* **MuJoCo camera frame**: the camera looks along its local −z with y up, so
  p_optical = diag(1, −1, −1) p_mujoco (:data:`MUJOCO_TO_OPTICAL`, a rotation by π about x);
  :func:`optical_pose` converts a MuJoCo camera's world pose.
* **Pixels** (u, v): column and row of the image as ``mujoco.Renderer`` returns it (row 0 at
  the top), pixel centres at integers, so the principal point of an ideal camera is
  ((W − 1)/2, (H − 1)/2). Projection: u = c_u + f_u X/Z, v = c_v + f_v Y/Z.
* **Features** s: (k, 2) pixel coordinates of k points (or flattened (2k,) as (u₁, v₁, u₂, …)).
* **Rows**: :func:`optical_pose`, :func:`camera_points`, :func:`normalise`,
  :func:`interaction_matrix`, :func:`homography`, :func:`planar_pose`, :func:`pose_error`,
  :func:`transform_points` and :func:`damped_pinv` also take rows of observations, a leading
  batch axis N (features (N, k, 2), poses (N, 3, 3) and (N, 3), matrices (N, m, n)), one
  observation being the one-row case: element-wise numpy and one LAPACK call per row's
  matrix, so a row gives the same numbers alone or in a batch.
* **Camera twist** (v, ω) (6,): linear velocity of the optical centre (m/s) and angular
  velocity (rad/s), both in the optical frame of the moving camera.

The interaction matrix is the notes' point-feature form (control-laws.md §7): for a point at
depth Z with image coordinates x = u − c_u, y = v − c_v (px, relative to the principal point)
and focal length λ (px),

    [ẋ; ẏ] = [[−λ/Z, 0, x/Z, xy/λ, −(λ² + x²)/λ, y], [0, −λ/Z, y/Z, (λ² + y²)/λ, −xy/λ, −x]] [v; ω]

(with f_u ≠ f_v the rows are scaled by f_u and f_v of the normalised form x_n = X/Z).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import mujoco
import numpy as np

from cir_gym import trajectories as traj

__all__ = [
    "CAMERA_GEOM_GROUPS",
    "MARKER_COLOURS",
    "MUJOCO_TO_OPTICAL",
    "Camera",
    "camera_points",
    "damped_pinv",
    "detect_markers",
    "encloses",
    "homography",
    "interaction_matrix",
    "normalise",
    "optical_pose",
    "planar_pose",
    "pose_error",
    "project",
    "transform_points",
    "twist_between",
    "visible",
]

#: p_optical = MUJOCO_TO_OPTICAL @ p_mujoco: MuJoCo cameras look along −z with y up.
MUJOCO_TO_OPTICAL = np.diag([1.0, -1.0, -1.0])
#: saturated marker colours (RGB in [0, 1]) in the order of the features: red, green, blue,
#: yellow
MARKER_COLOURS = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (1.0, 1.0, 0.0))
#: geom groups a camera sees (``visible``): all but group 1, which the robot files use for
#: translucent placeholders (the flange payload) that are not part of the scene's objects
CAMERA_GEOM_GROUPS = np.array([1, 0, 1, 1, 1, 1], dtype=np.uint8)


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics (no distortion) and the image size.

    Attributes:
        width, height: image size (px).
        fu, fv: focal lengths (px) along u and v.
        cu, cv: principal point (px, pixel centres at integers).
    """

    width: int
    height: int
    fu: float
    fv: float
    cu: float
    cv: float

    @classmethod
    def from_fovy(cls, fovy: float, width: int, height: int) -> Camera:
        """An ideal camera with MuJoCo's vertical field of view ``fovy`` (deg), square pixels:
        f = (H/2) / tan(fovy/2), principal point at the image centre."""
        if not 0.0 < fovy < 180.0:
            raise ValueError(f"fovy must be in (0, 180) deg, got {fovy!r}")
        f = 0.5 * height / np.tan(np.deg2rad(fovy) / 2.0)
        return cls(int(width), int(height), f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    @classmethod
    def from_model(cls, model: mujoco.MjModel, camera: str | int, width: int, height: int
                   ) -> Camera:
        """The intrinsics MuJoCo renders camera ``camera`` of ``model`` with at width × height."""
        cid = camera if isinstance(camera, int) else mujoco.mj_name2id(
            model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
        if cid < 0 or cid >= model.ncam:
            raise ValueError(f"camera {camera!r} not in the model")
        return cls.from_fovy(float(model.cam_fovy[cid]), width, height)

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix (3, 3)."""
        return np.array([[self.fu, 0.0, self.cu], [0.0, self.fv, self.cv], [0.0, 0.0, 1.0]])

    def with_error(self, focal_scale: float = 1.0,
                   principal_offset: tuple[float, float] = (0.0, 0.0)) -> Camera:
        """This camera with its focal lengths scaled and its principal point moved (px)."""
        return replace(self, fu=self.fu * focal_scale, fv=self.fv * focal_scale,
                       cu=self.cu + principal_offset[0], cv=self.cv + principal_offset[1])

    def inside(self, s: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(k,) True where the features s (k, 2) are at least ``margin`` px inside the image
        (the image spans [−0.5, W − 0.5] × [−0.5, H − 0.5])."""
        s = np.asarray(s, dtype=float).reshape(-1, 2)
        lo = -0.5 + margin
        return ((s[:, 0] >= lo) & (s[:, 0] <= self.width - 0.5 - margin)
                & (s[:, 1] >= lo) & (s[:, 1] <= self.height - 0.5 - margin))


def optical_pose(xpos: np.ndarray, xmat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World pose (p (3,), R (3, 3) optical→world) of a MuJoCo camera from ``cam_xpos`` (3,)
    and ``cam_xmat`` (9,) (camera→world): R = R_mujoco · MUJOCO_TO_OPTICAL (its own inverse);
    rows p (N, 3), R (N, 3, 3) of rows (N, 3), (N, 9)."""
    p = np.array(xpos, dtype=float)
    return p, np.asarray(xmat, dtype=float).reshape(*p.shape[:-1], 3, 3) @ MUJOCO_TO_OPTICAL


def transform_points(R: np.ndarray, t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """R p + t (k, 3) for each row p of ``points`` (k, 3); rows of poses R (..., 3, 3),
    t (..., 3) give (..., k, 3)."""
    R = np.asarray(R)
    t = np.asarray(t)
    return np.asarray(points, dtype=float) @ R.swapaxes(-1, -2) + (
        t[..., None, :] if R.ndim > 2 else t)


def project(points_camera: np.ndarray, camera: Camera) -> np.ndarray:
    """Pixel coordinates (k, 2) of points (k, 3) in the optical frame.

    Raises:
        ValueError: a point at or behind the optical centre (Z ≤ 0), which has no image.
    """
    P = np.asarray(points_camera, dtype=float).reshape(-1, 3)
    Z = P[:, 2]
    if np.any(Z <= 0.0):
        raise ValueError(f"points behind the camera (Z ≤ 0) have no image: Z = {Z}")
    return np.column_stack((camera.cu + camera.fu * P[:, 0] / Z,
                            camera.cv + camera.fv * P[:, 1] / Z))


def _pixel_features(s: np.ndarray) -> np.ndarray:
    """Features s (..., k, 2) px: (k, 2) and rows (..., k, 2) as they are, (2k,) as (k, 2).

    Raises:
        ValueError: any other shape.
    """
    s = np.asarray(s, dtype=float)
    if s.ndim == 1 and s.size % 2 == 0:
        s = s.reshape(-1, 2)  # (u₁, v₁, u₂, …)
    if s.ndim < 2 or s.shape[-1] != 2:
        raise ValueError(f"s must be pixel features (k, 2), (2k,) or rows (..., k, 2), got shape "
                         f"{np.shape(s)}")
    return s


def normalise(s: np.ndarray, camera: Camera) -> np.ndarray:
    """Normalised image coordinates x_n = (u − c_u)/f_u = X/Z, y_n = (v − c_v)/f_v = Y/Z of
    pixel features s: (k, 2) of s (k, 2) or (2k,), rows (N, k, 2) of rows s (N, k, 2)."""
    return (_pixel_features(s) - (camera.cu, camera.cv)) / (camera.fu, camera.fv)


def interaction_matrix(s: np.ndarray, depth: np.ndarray | float, camera: Camera) -> np.ndarray:
    """Interaction matrix L (2k, 6) of k point features: ṡ = L (v, ω), ṡ in px/s; rows
    (N, 2k, 6) of rows of features.

    Args:
        s: (k, 2) or (2k,) pixel features, or rows of them (N, k, 2).
        depth: depths Z (m) of the points in the optical frame (> 0): (k,) or a scalar, or
            rows (N, k) (anything that broadcasts to s's (..., k)).
        camera: the intrinsics (the notes' λ is f_u = f_v).

    Rows 2i, 2i+1 are the notes' L(λ, x, y, Z) of point i (module docstring): the normalised
    form [[−1/Z, 0, x/Z, xy, −(1 + x²), y], [0, −1/Z, y/Z, 1 + y², −xy, −x]] with the u row
    scaled by f_u and the v row by f_v.

    Raises:
        ValueError: a depth that is not finite or not > 0.
    """
    xn = normalise(s, camera)
    Z = np.broadcast_to(np.asarray(depth, dtype=float), xn.shape[:-1])
    if not np.all(np.isfinite(Z)) or np.any(Z <= 0.0):
        raise ValueError(f"depth must be finite and > 0, got {Z}")
    x, y = xn[..., 0], xn[..., 1]
    L = np.empty((*xn.shape[:-1], 2, 6))  # (..., k, 2, 6): the u and v rows of point i
    u, v = L[..., 0, :], L[..., 1, :]
    u[..., 0], u[..., 1], u[..., 2] = -1.0 / Z, 0.0, x / Z
    u[..., 3], u[..., 4], u[..., 5] = x * y, -(1.0 + x * x), y
    v[..., 0], v[..., 1], v[..., 2] = 0.0, -1.0 / Z, y / Z
    v[..., 3], v[..., 4], v[..., 5] = 1.0 + y * y, -x * y, -x
    u *= camera.fu
    v *= camera.fv
    return L.reshape(*xn.shape[:-2], 2 * xn.shape[-2], 6)  # rows 2i, 2i+1: point i


def homography(plane_points: np.ndarray, image_points: np.ndarray) -> np.ndarray:
    """Homography H (3, 3), ‖H‖_F = 1, with (x, y, 1) ∝ H (X, Y, 1) for k ≥ 4 correspondences
    of plane points (k, 2) and normalised image points (k, 2): the direct linear transform
    (the null vector of the 2k × 9 system, exact for 4 points in general position). Rows of
    image points (N, k, 2) (the plane points shared) give rows H (N, 3, 3), one SVD per row.

    Raises:
        ValueError: image points that are not (..., k, 2) for the k plane points.
    """
    P = np.asarray(plane_points, dtype=float)
    m = np.asarray(image_points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 2 or m.shape[-2:] != P.shape:
        raise ValueError(f"homography needs plane points (k, 2) and image points (..., k, 2), "
                         f"got shapes {P.shape} and {m.shape}")
    P_h = np.column_stack((P, np.ones(len(P))))  # (X, Y, 1) (k, 3)
    A = np.zeros((*m.shape, 9))  # (..., k, 2, 9): rows 2i (x), 2i+1 (y) of point i
    A[..., 0, :3] = P_h
    A[..., 1, 3:6] = P_h
    A[..., 6:] = -m[..., None] * P_h[:, None]  # −x (X, Y, 1) and −y (X, Y, 1)
    A = A.reshape(*m.shape[:-2], 2 * len(P), 9)
    return np.linalg.svd(A)[2][..., -1, :].reshape(*m.shape[:-2], 3, 3)


def planar_pose(model_points: np.ndarray, s: np.ndarray, camera: Camera
                ) -> tuple[np.ndarray, np.ndarray]:
    """Pose (R, t) of a planar target in the optical frame from k ≥ 4 of its points.

    ``model_points`` (k, 3) lie in the target's plane z = 0 (target frame); ``s`` (k, 2) are
    their pixel features, or rows of them (N, k, 2). The homography H ∝ [r₁ r₂ t]
    (normalised coordinates) is decomposed: scale 1/‖h₁‖ (mean of ‖h₁‖, ‖h₂‖) with the sign
    that puts the target in front (t_z > 0), r₃ = r₁ × r₂, and the nearest rotation (SVD).
    Exact on noise-free points.

    Returns:
        R (3, 3) target→camera and t (3,) the target origin in the optical frame (m); rows
        R (N, 3, 3), t (N, 3) of rows of features.

    Raises:
        ValueError: model points off the plane z = 0.
    """
    P = np.asarray(model_points, dtype=float).reshape(-1, 3)
    if np.any(np.abs(P[:, 2]) > 1e-12):
        raise ValueError("planar_pose needs model points in the plane z = 0")
    H = homography(P[:, :2], normalise(s, camera))
    h1, h2 = H[..., :, 0], H[..., :, 1]
    scale = 2.0 / (np.sqrt(np.sum(h1 * h1, axis=-1)) + np.sqrt(np.sum(h2 * h2, axis=-1)))
    H = H * scale[..., None, None]
    H = np.where(H[..., 2:, 2:] < 0.0, -H, H)  # t_z = H[2, 2] > 0: the target in front
    M = H.copy()
    M[..., :, 2] = _cross(H[..., :, 0], H[..., :, 1])  # [r₁ r₂ r₁ × r₂]
    U, _, Vt = np.linalg.svd(M)
    U[..., :, 2] *= np.linalg.det(U @ Vt)[..., None]  # U diag(1, 1, det(U Vᵀ))
    return U @ Vt, H[..., :, 2].copy()


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b (..., 3) of rows of 3-vectors (np.cross's formula without its axis handling)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack((a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), axis=-1)


def pose_error(R: np.ndarray, t: np.ndarray, R_ref: np.ndarray, t_ref: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Pose of the current camera in the desired camera's frame from the target's pose in
    both: (R, t) target→current camera, (R_ref, t_ref) target→desired camera (R (3, 3),
    t (3,), or rows of them (N, 3, 3), (N, 3)).

    Returns:
        t_e (3,): the current optical centre in the desired frame, c*t_c = t_ref − R_e t (m);
        θu (3,): the rotation vector of c*R_c = R_ref Rᵀ (rad, θ ∈ [0, π]); rows (N, 3) each
        of rows of poses.
    """
    R_e = np.asarray(R_ref) @ np.asarray(R).swapaxes(-1, -2)  # c*R_c
    t_e = np.asarray(t_ref) - (R_e @ np.asarray(t)[..., None])[..., 0]
    if R_e.ndim == 2:
        return t_e, _rotation_vector(R_e)
    return t_e, np.stack([_rotation_vector(R_i) for R_i in R_e.reshape(-1, 3, 3)]
                         ).reshape(t_e.shape)  # row by row


def _rotation_vector(R: np.ndarray) -> np.ndarray:
    """θu (3,) (rad) of a rotation R (3, 3), θ ∈ [0, π]."""
    axis, theta = traj.axis_angle_from_matrix(R)
    return axis * theta


def twist_between(R_e: np.ndarray, t_e: np.ndarray) -> np.ndarray:
    """W (6, 6) = [[R, [t]× R], [0, R]]: a rigid motion's twist described in frame b → in a.

    The pose of frame b in frame a is (R_e, t_e). With (v_b, ω_b) the velocity of b's origin
    and the angular velocity, in b's axes, the same motion described by the velocity of the
    point at a's origin and the angular velocity, in a's axes, is
    v_a = R v_b + t × (R ω_b), ω_a = R ω_b (since v_a = v_b + ω × (p_a − p_b)).
    """
    R = np.asarray(R_e, dtype=float)
    t = np.asarray(t_e, dtype=float)
    W = np.zeros((6, 6))
    W[:3, :3] = R
    W[:3, 3:] = traj.skew(t) @ R
    W[3:, 3:] = R
    return W


def camera_points(points_world: np.ndarray, position: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Points (k, 3) of the world in the optical frame of a camera at ``position`` (3,) with
    orientation ``R`` (3, 3, optical → world): Rᵀ (p − position); rows (N, k, 3) of rows of
    points (N, k, 3) and cameras (N, 3), (N, 3, 3)."""
    position = np.asarray(position, dtype=float)
    return (np.asarray(points_world, dtype=float) - position[..., None, :]) @ np.asarray(R)


def damped_pinv(A: np.ndarray, damping: float) -> np.ndarray:
    """Damped least-squares inverse A* = Aᵀ (A Aᵀ + μ² I)⁻¹ = (AᵀA + μ² I)⁻¹ Aᵀ (n, m) of A (m, n),
    or of each of rows of matrices A (N, m, n): A* (N, n, m), one SVD per row.

    The course's damped least squares (control-laws.md §1) for any shape: through the SVD
    A = U Σ Vᵀ, A* = V diag(σᵢ / (σᵢ² + μ²)) Uᵀ. A direction with σᵢ ≫ μ is inverted as by the
    pseudo-inverse (gain σᵢ² / (σᵢ² + μ²) of it), one with σᵢ ≪ μ is all but dropped, and
    ‖A* e‖ ≤ ‖e‖ / (2 μ) whatever A: no command grows without bound near a singularity.
    ``damping`` μ ≥ 0 is in the units of A's entries (μ = 0: the pseudo-inverse).
    """
    if not np.isfinite(damping) or damping < 0.0:
        raise ValueError(f"damping must be a finite number >= 0, got {damping!r}")
    if damping == 0.0:
        return np.linalg.pinv(A)
    U, sigma, Vt = np.linalg.svd(np.asarray(A, dtype=float), full_matrices=False)
    gains = sigma / (sigma * sigma + damping * damping)
    return (Vt.swapaxes(-1, -2) * gains[..., None, :]) @ U.swapaxes(-1, -2)


def detect_markers(
    image: np.ndarray,
    colours: tuple[tuple[float, ...], ...] = MARKER_COLOURS,
    min_pixels: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (k, 2) (u, v) px of saturated colour blobs in an RGB image, and found (k,).

    A pixel belongs to colour c (components 0 or 1) when its channels where c = 1 are ≥ 90,
    within 0.8× of each other (yellow is not orange) and at least 2.5× its channels where
    c = 0 (plus 20). Fewer than ``min_pixels`` pixels: not found (centroid NaN). Pixel centres
    at integer coordinates (row 0 at the top).
    """
    img = np.asarray(image, dtype=np.int32)
    out = np.full((len(colours), 2), np.nan)
    found = np.zeros(len(colours), dtype=bool)
    for i, c in enumerate(colours):
        on = np.array(c) > 0.5
        lit = np.min(img[..., on], axis=-1)
        dark = np.max(img[..., ~on], axis=-1) if np.any(~on) else np.zeros(img.shape[:2])
        mask = (lit >= 90) & (lit >= 0.8 * np.max(img[..., on], axis=-1)) & (lit >= 2.5 * dark + 20)
        rows, cols = np.nonzero(mask)
        if rows.size >= min_pixels:
            out[i] = cols.mean(), rows.mean()
            found[i] = True
    return out, found


def encloses(model: mujoco.MjModel, data: mujoco.MjData, geom: int, point: np.ndarray,
             direction: np.ndarray) -> bool:
    """True if the convex primitive geom ``geom`` encloses ``point``: rays from it both ways
    along ``direction`` meet its surface (from outside, at most one of them does). Meshes and
    planes: False."""
    kind = int(model.geom_type[geom])
    if kind in (int(mujoco.mjtGeom.mjGEOM_MESH), int(mujoco.mjtGeom.mjGEOM_PLANE),
                int(mujoco.mjtGeom.mjGEOM_HFIELD), int(mujoco.mjtGeom.mjGEOM_SDF)):
        return False
    pos, mat, size = data.geom_xpos[geom], data.geom_xmat[geom], model.geom_size[geom]
    return (mujoco.mju_rayGeom(pos, mat, size, point, direction, kind) >= 0.0
            and mujoco.mju_rayGeom(pos, mat, size, point, -direction, kind) >= 0.0)


def visible(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    position: np.ndarray,
    geoms: np.ndarray,
    near: float = 0.0,
) -> np.ndarray:
    """(k,) True where the centre of geom ``geoms[i]`` is in the line of sight of a camera at
    ``position`` (3,): a ray from the camera centre to the geom's centre (``mujoco.mj_ray``)
    meets no other geom first.

    The ray sees what the camera renders: geoms with alpha > 0, static ones too, all groups
    but 1 (:data:`CAMERA_GEOM_GROUPS`), nothing nearer than the near clipping distance
    ``near`` (m; MuJoCo's ``vis.map.znear`` × ``stat.extent``), and no geom that encloses the
    camera centre (a camera on a link sits inside the link's capsule, whose faces the renderer
    culls from inside; the ray passes on beyond it). The geom's own surface, which the ray
    meets before its centre, does not hide it; a disc seen from behind its plate, or behind a
    link, is hidden. Only the centre is tested: a marker partly covered with its centre in
    view counts as visible. ``data``'s geom poses must be current (``mj_kinematics``).
    """
    origin = np.asarray(position, dtype=float)
    hit = np.zeros(1, dtype=np.int32)
    out = np.zeros(len(geoms), dtype=bool)
    for i, g in enumerate(geoms):
        target = data.geom_xpos[g]
        distance = float(np.linalg.norm(target - origin))
        if distance <= near:  # nearer than the near plane: not rendered
            continue
        direction = (target - origin) / distance
        start = origin + near * direction
        while True:
            ray = target - start  # x = 1 at the geom's centre
            x = mujoco.mj_ray(model, data, start, ray, CAMERA_GEOM_GROUPS, 1, -1, hit)
            if x < 0.0 or x >= 1.0 or hit[0] == g:
                out[i] = True
                break
            if not encloses(model, data, int(hit[0]), origin, direction):
                break  # something in between: hidden
            start = start + x * ray + 1e-9 * direction  # beyond the enclosing geom's face
    return out
