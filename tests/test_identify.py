"""`cir-gym identify`: identification on the true simulator hands computed torque a model."""

from __future__ import annotations

from scripts.identify import run_identify


def test_noise_free_identification_gives_computed_torque_the_exact_model_accuracy(tmp_path):
    rms = run_identify(payload_mass=3.0, duration=10.0, noise=0.0, seed=1, episodes=1,
                       out=tmp_path)
    identified = rms["computed_torque (identified model)"]
    assert identified <= 1.05 * rms["computed_torque (exact model)"]
    assert identified < 0.05 * rms["computed_torque (nominal model)"]
    assert (tmp_path / "README.md").exists()
