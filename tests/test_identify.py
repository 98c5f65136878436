"""`cir-gym identify`: identification on the true simulator hands computed torque a model."""

from __future__ import annotations

import numpy as np
import pytest

from cir_gym.scoring.identify import (
    excitation_data,
    run_identify,
    savgol_coefficients,
    savgol_filter,
)


def test_noise_free_identification_gives_computed_torque_the_exact_model_accuracy(tmp_path):
    rms = run_identify(payload_mass=3.0, duration=10.0, noise=0.0, seed=1, episodes=1,
                       out=tmp_path, differentiation="exact")
    identified = rms["computed_torque (identified model)"]
    assert identified <= 1.05 * rms["computed_torque (exact model)"]
    assert identified < 0.05 * rms["computed_torque (nominal model)"]
    assert (tmp_path / "README.md").exists()


def test_noisy_measurements_through_the_filter_reach_2x_the_exact_model_error(tmp_path):
    """Quantized encoders (1e-5 rad), torque noise, q̇ and q̈ by filtered differentiation.
    Measured on seeds 0, 1, 2: 1.35×, 1.12×, 1.32×."""
    rms = run_identify(payload_mass=3.0, duration=15.0, noise=0.05, seed=1, episodes=1,
                       out=tmp_path, encoder_resolution=1e-5)
    identified = rms["computed_torque (identified model)"]
    assert identified <= 2.0 * rms["computed_torque (exact model)"]
    assert identified < 0.05 * rms["computed_torque (nominal model)"]
    assert "quantized to 1e-05 rad" in (tmp_path / "README.md").read_text()


@pytest.mark.parametrize("derivative", [0, 1, 2])
def test_savgol_filter_is_exact_on_polynomials_of_its_order_and_has_no_delay(derivative):
    dt, m = 1e-3, 20
    t = np.arange(200) * dt
    coeffs = np.array([0.3, -1.0, 2.0, 5.0, -7.0])  # a quartic
    x = np.polynomial.polynomial.polyval(t, coeffs)[:, None]
    expected = np.polynomial.polynomial.polyval(
        t, np.polynomial.polynomial.polyder(coeffs, derivative)
    )[m:-m]
    y = savgol_filter(x, m, 4, derivative, dt)[:, 0]
    np.testing.assert_allclose(y, expected, rtol=1e-6, atol=1e-6 * np.max(np.abs(expected)))
    c = savgol_coefficients(m, 4, derivative, dt)
    np.testing.assert_allclose(c, (-1) ** derivative * c[::-1], atol=1e-9 * np.max(np.abs(c)))


def test_filtered_differentiation_recovers_qdd_where_finite_differences_drown_in_quantization():
    m = 50
    q, qd, qdd, _ = excitation_data(3.0, 3.0, 0.0, 2, differentiation="exact")
    _, qd_f, qdd_f, _ = excitation_data(3.0, 3.0, 0.0, 2, encoder_resolution=1e-5,
                                        half_window=m)
    scale = np.sqrt(np.mean(qdd[m:-m] ** 2))
    assert np.sqrt(np.mean((qdd_f - qdd[m:-m]) ** 2)) < 0.05 * scale
    assert np.sqrt(np.mean((qd_f - qd[m:-m]) ** 2)) < 0.01 * np.sqrt(np.mean(qd**2))
    quantized = np.round(q / 1e-5) * 1e-5
    naive = np.diff(quantized, 2, axis=0) / 1e-3**2  # second difference of the encoder
    assert np.sqrt(np.mean((naive - qdd[1:-1]) ** 2)) > scale


def test_spread_reports_every_seed_and_noise_level_with_median_and_range(tmp_path, monkeypatch):
    """The headline must be a spread, not one run: one ratio per (noise, seed), a median and a
    range per noise level and overall."""
    import cir_gym.scoring.identify as identify

    fake = {(0.1, 0): 1.5, (0.1, 1): 2.5, (0.3, 0): 1.9, (0.3, 1): 3.1}

    def run(payload_mass, duration, noise, seed, episodes, out):
        return {"computed_torque (identified model)": fake[noise, seed],
                "computed_torque (exact model)": 1.0}

    monkeypatch.setattr(identify, "run_identify", run)
    ratios = identify.identification_spread((0, 1), (0.1, 0.3), out=tmp_path)
    assert ratios == fake
    text = (tmp_path / "spread.md").read_text()
    assert "| 0.1 | 1.50× | 2.50× | 2.00× | 1.50–2.50× |" in text
    assert "median 2.20×, range 1.50–3.10×; 2 of 4 within the 2× target" in text
