"""The one cross-product matrix S(v), S(v) x = v × x: ``cir_gym.trajectories.skew``."""

from __future__ import annotations

import numpy as np
import pytest

from cir_gym import operational_space, trajectories
from cir_gym.dynamics import _spatial
from cir_gym.trajectories import skew


def test_the_textbook_matrix_and_its_sign() -> None:
    """S(v) = [[0, −v_z, v_y], [v_z, 0, −v_x], [−v_y, v_x, 0]] and S(e_x) e_y = e_z (cyclic);
    Sᵀ = −S, so a transposed convention fails here."""
    np.testing.assert_array_equal(
        skew(np.array([1.0, 2.0, 3.0])), [[0.0, -3.0, 2.0], [3.0, 0.0, -1.0], [-2.0, 1.0, 0.0]]
    )
    e_x, e_y, e_z = np.eye(3)
    np.testing.assert_array_equal(skew(e_x) @ e_y, e_z)
    np.testing.assert_array_equal(skew(e_y) @ e_z, e_x)
    np.testing.assert_array_equal(skew(e_z) @ e_x, e_y)


def test_it_is_the_cross_product_for_one_vector_and_for_rows() -> None:
    """S(v) x = v × x (to 1e-15: the product of S and x sums in another order than np.cross)
    for v (3,) and rows (5, 4, 3); each row's S equals the single vector's exactly."""
    rng = np.random.default_rng(0)
    v, x = rng.standard_normal((5, 4, 3)), rng.standard_normal((5, 4, 3))
    S = skew(v)
    assert S.shape == (5, 4, 3, 3)
    np.testing.assert_allclose((S @ x[..., None])[..., 0], np.cross(v, x), rtol=0, atol=1e-15)
    np.testing.assert_allclose(skew(v[0, 0]) @ x[0, 0], np.cross(v[0, 0], x[0, 0]), atol=1e-15)
    single = np.stack([skew(r) for r in v.reshape(-1, 3)]).reshape(S.shape)
    np.testing.assert_array_equal(S, single)
    np.testing.assert_array_equal(np.swapaxes(S, -1, -2), -S)


def test_lists_and_integers_give_floats() -> None:
    assert skew([1, 2, 3]).dtype == np.float64
    np.testing.assert_array_equal(skew([1, 2, 3]), skew(np.array([1.0, 2.0, 3.0])))
    np.testing.assert_array_equal(skew(np.array([[1, 2, 3]])), skew([[1.0, 2.0, 3.0]]))


@pytest.mark.parametrize("v", [np.zeros(4), np.zeros((5, 2)), 1.0, [1.0, 2.0]])
def test_another_shape_is_an_error_naming_v(v: object) -> None:
    with pytest.raises(ValueError, match=r"v must have shape \(3,\) or \(\.\.\., 3\)"):
        skew(v)


def test_one_implementation() -> None:
    """The operational space and the dynamics use this function, not copies."""
    assert operational_space.skew is trajectories.skew
    assert _spatial.skew is trajectories.skew
