"""PegInHole's contacts: the forces between the robot and the block, and the bore's contact flags.

Every contact of the scene is between the robot (the arm's links, the peg's holder, the peg) and
the block (:func:`cir_gym.peg_hole_geometry.build_peg_in_hole`: nothing else collides). MuJoCo's
contact sensors of the scene (``peg_hole_geometry._add_contact_sensors``) measure them in C at
every physics step, from that step's constraint forces, so a physics step's contacts are a slice
of ``sensordata``: of one env (nsensordata,), or of a batch or a control period's steps
(..., nsensordata). A real part is damaged by the force of one contact, so the force limit and
the ``peak_force`` metric read the largest single contact; the net force (their vector sum, in
which opposing wall forces cancel) is what the wrist sensor feels.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from cir_gym import peg_hole_geometry as geo
from cir_gym.envs.contact_force import largest_contact_force

__all__ = ["SIDE_NORMAL", "STALL_SPEED", "ContactFlags", "ContactSensors", "contact_flags"]

#: |n · axis| below this: a contact on the bore's side (else on the top face or the bottom)
SIDE_NORMAL = 0.7
#: m/s: axial speed below which a peg in two-point contact counts as stuck
STALL_SPEED = 1e-3


class ContactSensors:
    """Where the scene's contact sensors are in ``sensordata``, and their readings.

    Each method takes ``sensordata`` of shape (..., nsensordata) (one env, a batch, a period's
    physics steps) and returns arrays with its leading shape.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        def address(name: str) -> int:
            return int(model.sensor_adr[model.sensor(name).id])

        ids = [model.sensor(name).id for name in geo.HISTORY_SENSORS]
        #: physics steps in the history buffer (0: none)
        self.steps = K = int(model.sensor_history[ids[0], 0])
        # the history's layout per sensor (MuJoCo's ring buffer): [·, slot of the newest
        # sample, K times, K × dim values]; the sensors are written together, so one slot
        # index is every sensor's. _gather[h, k]: where the values of the k-th oldest sample
        # are when the newest is in slot h, for the sensordata columns _columns
        self._columns = np.concatenate(
            [np.arange(model.sensor_adr[i], model.sensor_adr[i] + model.sensor_dim[i]) for i in ids]
        )
        self._newest = int(model.sensor_historyadr[ids[0]]) + 1
        self._gather = np.array([
            [
                np.concatenate([
                    model.sensor_historyadr[i] + 2 + K + (h + 1 + k) % K * model.sensor_dim[i]
                    + np.arange(model.sensor_dim[i])
                    for i in ids
                ])
                for k in range(K)
            ]
            for h in range(K)
        ]) if K else np.zeros((0, 0, len(self._columns)), dtype=int)
        self._largest = address(geo.LARGEST_CONTACT)
        self._net = address(geo.NET_CONTACT)
        self._peg = address(geo.PEG_CONTACTS)
        self.slots = geo.PEG_CONTACT_SLOTS
        self._ft = address("ft_force"), address("ft_torque")

    def period(self, history: np.ndarray, out: np.ndarray) -> None:
        """The physics steps of a control period from MuJoCo's history buffer ``history``
        (..., nhistory): into ``out`` (..., steps, nsensordata), oldest first, the values of
        :data:`~cir_gym.peg_hole_geometry.HISTORY_SENSORS` at their sensordata addresses
        (the other columns are left as they are)."""
        where = self._gather[history[..., self._newest].astype(np.int64)]  # (..., steps, d)
        if history.ndim == 1:
            out[:, self._columns] = history[where]
        else:
            flat = where.reshape(len(history), -1)
            values = np.take_along_axis(history, flat, axis=-1).reshape(where.shape)
            out[..., self._columns] = values

    def largest_force(self, sensordata: np.ndarray) -> np.ndarray:
        """The force of the contact with the largest force (..., 3), its contact frame (N)."""
        return sensordata[..., self._largest : self._largest + 3]

    def largest(self, sensordata: np.ndarray) -> np.ndarray:
        """The largest single contact force max_i ‖f_i‖ (...,) (N; 0 without contact): the
        whole force (normal and friction) of the largest contact
        (:func:`~cir_gym.envs.contact_force.largest_contact_force`)."""
        return largest_contact_force(self.largest_force(sensordata))

    def net(self, sensordata: np.ndarray) -> np.ndarray:
        """The net force of the block on the robot Σ_i f_i (..., 3), world frame (N) (the
        sensor gives the robot's force on the block)."""
        return -sensordata[..., self._net : self._net + 3]

    def peg_count(self, sensordata: np.ndarray) -> np.ndarray:
        """The number of the peg's contacts with the block (...,) (the sensor's ``found``)."""
        return sensordata[..., self._peg]

    def peg(self, sensordata: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The peg's strongest contacts (``slots`` of them, empty slots zero): unit normals
        pushing the peg away from the block (..., slots, 3), world frame, and normal forces
        (..., slots) (N; > 0 when the contact pushes)."""
        start = self._peg
        rows = sensordata[..., start : start + 7 * self.slots]
        rows = rows.reshape(*rows.shape[:-1], self.slots, 7)  # found, force (3), normal (3)
        return -rows[..., 4:7], rows[..., 1]

    def wrist(self, sensordata: np.ndarray) -> np.ndarray:
        """The wrist's true wrench (..., 6): force, torque in the sensor frame (N, N m)."""
        f, t = self._ft
        return np.concatenate((sensordata[..., f : f + 3], sensordata[..., t : t + 3]), axis=-1)


@dataclass(frozen=True)
class ContactFlags:
    """The peg's contact state in the bore (see PegInHole's Episode End): bools for one env,
    (N,) bool arrays for a batch.

    Attributes:
        two_point: contacts on the bore's side on opposite sides.
        wedged: two-point contact shallower than μ D (Whitney's wedging condition).
        jammed: two-point contact deeper than μ D while the peg does not advance.
    """

    two_point: bool | np.ndarray = False
    wedged: bool | np.ndarray = False
    jammed: bool | np.ndarray = False


def contact_flags(
    normal: np.ndarray,
    pressing: np.ndarray,
    axis: np.ndarray,
    depth: np.ndarray | float,
    axial_speed: np.ndarray | float,
    mu_diameter: float,
) -> ContactFlags:
    """Two-point contact, wedging and jamming from the peg's contacts, for one env or a batch
    (leading shape ``...``: () or (N,)).

    Args:
        normal: (..., k, 3) unit contact normals pushing the peg away from the block (zero
            for an empty slot).
        pressing: (..., k) normal force of each contact (N).
        axis: (..., 3) the true bore axis, world frame (out of the hole).
        depth: (...) tip depth in the true hole (m).
        axial_speed: (...) tip speed along the axis (m/s).
        mu_diameter: μ D, the friction coefficient times the hole diameter (m).
    """
    along = (normal @ axis[..., None])[..., 0]  # n · axis
    side = (np.abs(along) < SIDE_NORMAL) & (pressing > 0)
    if side.ndim == 1 and np.count_nonzero(side) < 2:  # one env with fewer than two
        return ContactFlags()
    lateral = normal - along[..., None] * axis[..., None, :]
    lateral /= np.maximum(np.linalg.norm(lateral, axis=-1, keepdims=True), 1e-12)
    cosines = lateral @ np.swapaxes(lateral, -1, -2)  # (..., k, k)
    facing = (cosines < -0.5) & side[..., :, None] & side[..., None, :]
    two_point = np.any(facing, axis=(-2, -1))  # two side contacts facing each other
    wedged = two_point & (np.asarray(depth) < mu_diameter)
    jammed = two_point & ~wedged & (np.abs(axial_speed) < STALL_SPEED)
    if two_point.ndim == 0:
        return ContactFlags(bool(two_point), bool(wedged), bool(jammed))
    return ContactFlags(two_point, wedged, jammed)
