"""The largest single contact force, one definition for the contact tasks (PegInHole's robot–block
contacts, AdmittanceContact's contacts on the plate).

A part is loaded by the whole force of a contact: the normal force and the friction together.
A MuJoCo contact sensor with ``data="force"`` and ``reduce="maxforce"`` reports, among the
contacts it watches, the one whose force has the largest magnitude, as that force
f = (f_n, f_t1, f_t2) in the contact's frame (N). Its magnitude ‖f‖ = max_i ‖f_i‖ is the
largest single contact force; the frame does not matter for a magnitude. Its normal component
f_n alone is not: another contact with a smaller total force can press harder along its normal.
"""

from __future__ import annotations

import numpy as np

__all__ = ["largest_contact_force"]


def largest_contact_force(reading: np.ndarray) -> np.ndarray:
    """The largest single contact force max_i ‖f_i‖ (...,) (N; 0 without contact), the
    magnitude of a ``maxforce`` contact sensor's force ``reading`` (..., 3) (contact frame:
    normal, two tangential; any leading shape: one env, a batch, a period's physics steps)."""
    return np.sqrt(np.sum(reading * reading, axis=-1))
