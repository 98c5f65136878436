"""Least-squares identification of the base (identifiable) dynamic parameters.

Stack τ̄ = Ȳ π over N samples and solve π̂ = Ȳ† τ̄. Only some linear combinations of π — the
*base parameters* π_b = K π — change the torques, so the problem is solved for π_b:

1. Structure (a property of the kinematics, not of the data): the regressor is stacked over
   random configurations, velocities and accelerations (fixed seed), its columns are scaled to
   unit norm, and a QR factorisation with column pivoting (greedy Gram-Schmidt, largest
   remaining column first; ties go to the lower index) picks r independent columns, the base
   columns; a column is dependent when its remaining norm falls below ``rank_tol``. The other
   columns are least-squares combinations of them, Y_d = Y_b β, hence
   Y π = Y_b (π[base] + β π[dependent]) = Y_b K π with K = [I β] (columns reordered).
2. Estimate: π̂_b = Ȳ_b† τ̄ by ``np.linalg.lstsq`` on the column-scaled base regressor.

With ``friction=True`` each joint gets a viscous (q̇_i) and a Coulomb (sign q̇_i) column, and
the parameter vector is [π (11 n), F_v (n), F_c (n)].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np
from numpy.typing import ArrayLike

from cir_gym.dynamics._checks import as_real_array, as_vector
from cir_gym.dynamics.chain import chain_model
from cir_gym.dynamics.dynamic_regressor import regressor
from cir_gym.dynamics.parameters import parameter_names

RANK_TOLERANCE = 1e-7
"""Relative remaining column norm below which a regressor column counts as dependent."""


def _friction_columns(qd: np.ndarray) -> np.ndarray:
    """[diag(q̇), diag(sign q̇)] per sample.  # (N, n) -> (N, n, 2 n)"""
    eye = np.eye(qd.shape[-1])
    return np.concatenate([qd[..., :, None] * eye, np.sign(qd)[..., :, None] * eye], axis=-1)


def _full_regressor(
    model: mujoco.MjModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, friction: bool
) -> np.ndarray:
    """Y of all samples, friction columns appended.  # (N, n, p)"""
    Y = regressor(model, q, qd, qdd)
    if friction:
        Y = np.concatenate([Y, _friction_columns(qd)], axis=-1)
    return Y


def _random_states(model: mujoco.MjModel, samples: int, seed: int) -> tuple[np.ndarray, ...]:
    """Random q (within the joint ranges, or ±π / ±1 m), q̇ and q̈ ~ N(0, 1).  # 3 x (N, n)"""
    chain = chain_model(model)
    joints = chain.topology.joints
    limited = model.jnt_limited[joints].astype(bool)
    default = np.where(chain.revolute, np.pi, 1.0)
    lower = np.where(limited, model.jnt_range[joints, 0], -default)
    upper = np.where(limited, model.jnt_range[joints, 1], default)
    rng = np.random.default_rng(seed)
    q = rng.uniform(lower, upper, size=(samples, chain.n))
    return q, rng.normal(size=(samples, chain.n)), rng.normal(size=(samples, chain.n))


def _pivoted_columns(A: np.ndarray, tol: float) -> list[int]:
    """Columns chosen by QR with column pivoting of A (unit-norm or zero columns)."""
    residual = A.copy()
    chosen: list[int] = []
    remaining = np.einsum("ij,ij->j", residual, residual)
    for _ in range(A.shape[1]):
        best = remaining.max()
        if best <= tol**2:
            break
        column = int(np.flatnonzero(remaining >= best * (1.0 - 1e-6))[0])  # ties: lowest index
        direction = residual[:, column] / np.sqrt(remaining[column])
        for _ in range(2):  # project out twice for orthogonality to working precision
            residual -= np.outer(direction, direction @ residual)
        chosen.append(column)
        remaining = np.einsum("ij,ij->j", residual, residual)
        remaining[chosen] = 0.0
    return chosen


def base_parameter_structure(
    model: mujoco.MjModel, *, friction: bool = False, rank_tol: float = RANK_TOLERANCE
) -> tuple[np.ndarray, np.ndarray]:
    """Base columns and the matrix K with π_b = K π (see the module docstring).

    Args:
        model: a serial chain.
        friction: include the viscous and Coulomb friction parameters.
        rank_tol: relative remaining norm below which a column is dependent.

    Returns:
        base_indices (r,) sorted indices into π, K (r, p).
    """
    n = chain_model(model).n
    p = 11 * n + (2 * n if friction else 0)
    samples = int(np.ceil(4 * p / n)) + 10
    q, qd, qdd = _random_states(model, samples, seed=0)
    Y = _full_regressor(model, q, qd, qdd, friction).reshape(-1, p)
    norms = np.linalg.norm(Y, axis=0)
    excited = norms > rank_tol * norms.max()
    A = np.where(excited, Y / np.where(excited, norms, 1.0), 0.0)
    base = np.array(sorted(_pivoted_columns(A, rank_tol)), dtype=int)
    dependent = np.setdiff1d(np.arange(p), base)
    beta_scaled = np.linalg.lstsq(A[:, base], A[:, dependent], rcond=None)[0]
    beta_scaled[np.abs(beta_scaled) < 1e-9] = 0.0  # exact zeros for relations that are absent
    K = np.zeros((base.size, p))
    K[:, base] = np.eye(base.size)
    # Y_d = A_d diag(n_d) = A_b β_s diag(n_d) = Y_b diag(1/n_b) β_s diag(n_d)
    K[:, dependent] = beta_scaled / norms[base][:, None] * norms[dependent][None, :]
    return base, K


def _combination_name(row: np.ndarray, names: tuple[str, ...]) -> str:
    """E.g. "link1.I_zz + link2.I_yy - 0.42*link2.mc_y + joint1.armature"."""
    text = ""
    for index in np.flatnonzero(row):
        coefficient = float(row[index])
        sign = "-" if coefficient < 0 else "+"
        magnitude = abs(coefficient)
        term = names[index] if abs(magnitude - 1.0) < 1e-9 else f"{magnitude:.6g}*{names[index]}"
        text += f" {sign} {term}" if text else ("-" if sign == "-" else "") + term
    return text


@dataclass(frozen=True, eq=False)
class IdentificationResult:
    """Least-squares estimate of the base parameters π_b = K π.

    Attributes:
        model: the model whose kinematics defined the regressor.
        friction: whether viscous and Coulomb friction were identified.
        parameter_names: names of the full parameter vector (π, then F_v and F_c).  # (p,)
        base_indices: indices of the base columns in the full vector.  # (r,)
        base_matrix: K, full → base parameters, π_b = K π.  # (r, p)
        base_parameters: the estimate π̂_b.  # (r,)
        condition_number: 2-norm condition number of the stacked (unscaled) base regressor Ȳ_b.
        residual_rms: RMS of τ̄ − Ȳ_b π̂_b over all samples and joints (N m or N).
        n_samples: number of samples N.
    """

    model: mujoco.MjModel = field(repr=False)
    friction: bool
    parameter_names: tuple[str, ...] = field(repr=False)
    base_indices: np.ndarray
    base_matrix: np.ndarray = field(repr=False)
    base_parameters: np.ndarray
    condition_number: float
    residual_rms: float
    n_samples: int

    @property
    def base_parameter_names(self) -> list[str]:
        """Each base parameter as its combination of full parameters, e.g. "I_zz + armature"."""
        return [_combination_name(row, self.parameter_names) for row in self.base_matrix]

    def predict_torque(self, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike) -> np.ndarray:
        """τ̂ = Y_b(q, q̇, q̈) π̂_b (+ friction).

        Args:
            q, qd, qdd: joint positions, velocities, accelerations.  # (n,) or (N, n)

        Returns:
            predicted joint torques/forces.  # (n,) or (N, n)
        """
        Y = regressor(self.model, q, qd, qdd)  # validates q, qd, qdd (real, shapes, finite)
        q_array = np.asarray(q, dtype=float)
        if self.friction:
            qd_array = np.asarray(qd, dtype=float)
            Y = np.concatenate([Y, _friction_columns(qd_array)], axis=-1)
        tau = Y[..., self.base_indices] @ self.base_parameters
        return tau.reshape(q_array.shape)

    def to_full_parameters(self, prior: ArrayLike | None = None) -> np.ndarray:
        """A full π (11 n) consistent with the estimate, for ``rnea(..., parameters=π)``.

        Any π with K π = π̂_b gives the same torques; this returns the one closest to ``prior``
        in the Euclidean norm, π = π₀ + K⁺ (π̂_b − K π₀), with π₀ = ``prior`` (e.g. a nominal
        model's ``inertial_parameters``) or zero (the minimum-norm solution). Nothing makes the
        non-identifiable part physical (positive masses, positive-definite inertias): start from
        a physical prior when a controller needs a plausible B(q). Friction is not included; see
        ``viscous_friction`` and ``coulomb_friction``.

        Args:
            prior: π₀, the values to keep where the data says nothing.  # (11 n,)

        Returns:
            π with the inertial parameters and armatures.  # (11 n,)
        """
        p = 11 * chain_model(self.model).n
        start = np.zeros(p) if prior is None else as_vector("prior", prior, p)
        rows = self.base_indices < p
        K = self.base_matrix[rows][:, :p]
        correction = self.base_parameters[rows] - K @ start
        return start + np.linalg.pinv(K) @ correction

    def _friction(self, offset: int) -> np.ndarray | None:
        """Entries 11 n + offset n ... of the estimate (NaN where not identifiable)."""
        if not self.friction:
            return None
        n = chain_model(self.model).n
        position = {int(index): k for k, index in enumerate(self.base_indices)}
        wanted = 11 * n + offset * n + np.arange(n)
        return np.array(
            [self.base_parameters[position[i]] if i in position else np.nan for i in wanted]
        )

    @property
    def viscous_friction(self) -> np.ndarray | None:
        """Identified viscous friction F_v per joint (N m s/rad or N s/m), None without friction."""
        return self._friction(0)

    @property
    def coulomb_friction(self) -> np.ndarray | None:
        """Identified Coulomb friction f_s per joint (N m or N), None without friction."""
        return self._friction(1)


def identify(
    model: mujoco.MjModel,
    q: ArrayLike,
    qd: ArrayLike,
    qdd: ArrayLike,
    tau: ArrayLike,
    *,
    friction: bool = False,
    rcond: float | None = None,
    rank_tol: float = RANK_TOLERANCE,
) -> IdentificationResult:
    """Identify the base dynamic parameters from measured motion and torques.

    Args:
        model: a serial chain; only its kinematics (and gravity) are used.
        q: joint positions of N samples.  # (N, n)
        qd: joint velocities.  # (N, n)
        qdd: joint accelerations.  # (N, n)
        tau: joint torques/forces.  # (N, n)
        friction: also identify viscous and Coulomb friction per joint.
        rcond: cut-off ratio for small singular values, passed to ``np.linalg.lstsq``
            (None: machine precision times the larger dimension).
        rank_tol: tolerance of the base-parameter structure (see ``base_parameter_structure``).

    Returns:
        The estimate; see ``IdentificationResult``.

    Raises:
        ValueError: complex values, wrong shapes, NaN/inf, or fewer equations than base
            parameters.
    """
    n = chain_model(model).n
    arrays = []
    for name, value in (("q", q), ("qd", qd), ("qdd", qdd), ("tau", tau)):
        array = as_real_array(name, value, f"(N, {n})")
        if array.ndim != 2 or array.shape[1] != n:
            raise ValueError(f"{name} has shape {array.shape}, expected (N, {n}) samples")
        if not np.isfinite(array).all():
            raise ValueError(f"{name} contains NaN or inf; expected finite values")
        arrays.append(array)
    if len({array.shape[0] for array in arrays}) != 1:
        shapes = ", ".join(str(array.shape) for array in arrays)
        raise ValueError(f"q, qd, qdd and tau need the same number of samples, got {shapes}")
    q_array, qd_array, qdd_array, tau_array = arrays
    base, K = base_parameter_structure(model, friction=friction, rank_tol=rank_tol)
    samples = q_array.shape[0]
    if samples * n < base.size:
        raise ValueError(
            f"{samples} samples give {samples * n} equations for {base.size} base parameters; "
            f"need at least {int(np.ceil(base.size / n))} samples"
        )
    Y = _full_regressor(model, q_array, qd_array, qdd_array, friction)
    Y_base = Y.reshape(samples * n, -1)[:, base]
    torques = tau_array.reshape(-1)
    scale = np.linalg.norm(Y_base, axis=0)
    scale[scale == 0.0] = 1.0
    solution = np.linalg.lstsq(Y_base / scale, torques, rcond=rcond)[0]
    estimate = solution / scale
    singular_values = np.linalg.svd(Y_base, compute_uv=False)
    condition = (
        float(singular_values[0] / singular_values[-1]) if singular_values[-1] > 0 else np.inf
    )
    residual = torques - Y_base @ estimate
    names = parameter_names(model)
    if friction:
        joints = [name.removesuffix(".armature") for name in names[10 * n :]]
        names += [f"{joint}.viscous" for joint in joints] + [f"{joint}.coulomb" for joint in joints]
    return IdentificationResult(
        model=model,
        friction=friction,
        parameter_names=tuple(names),
        base_indices=base,
        base_matrix=K,
        base_parameters=estimate,
        condition_number=condition,
        residual_rms=float(np.sqrt(np.mean(residual**2))),
        n_samples=samples,
    )
