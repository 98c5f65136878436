"""PegInHole's contacts: the forces between the robot and the block, and the bore's contact flags.

Every contact of the scene is between the robot (the arm's links, the peg's holder, the peg) and
the block (:func:`cir_gym.peg_hole_geometry.build_peg_in_hole`: nothing else collides). Each
contact's force is MuJoCo's ``mj_contactForce`` (normal and friction, contact frame), turned
into the world frame and signed as the force *on the robot*. A real part is damaged by the
force of one contact, so the force limit and the ``peak_force`` metric read the largest single
contact; the net force (their vector sum, in which opposing wall forces cancel) is what the
wrist sensor feels.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

__all__ = ["SIDE_NORMAL", "STALL_SPEED", "BlockContacts", "ContactFlags", "contact_flags"]

#: |n · axis| below this: a contact on the bore's side (else on the top face or the bottom)
SIDE_NORMAL = 0.7
#: m/s: axial speed below which a peg in two-point contact counts as stuck
STALL_SPEED = 1e-3


@dataclass(frozen=True)
class BlockContacts:
    """The robot–block contacts of one physics step.

    Attributes:
        robot_geom: (k,) the robot's geom of each contact.
        force: (k, 3) force of the block on the robot at each contact, world frame (N).
        normal: (k, 3) unit contact normal pushing the robot away from the block, world frame.
        pressing: (k,) normal force of each contact (N; > 0 when the contact pushes).
        largest: the largest single contact force max_i ‖f_i‖ (N; 0 without contact).
        net: (3,) the net force of the block on the robot Σ_i f_i, world frame (N).
    """

    robot_geom: np.ndarray
    force: np.ndarray
    normal: np.ndarray
    pressing: np.ndarray
    largest: float
    net: np.ndarray

    @classmethod
    def measure(
        cls, model: mujoco.MjModel, data: mujoco.MjData, block: np.ndarray
    ) -> BlockContacts:
        """Every contact of the step, each between the robot and a geom with ``block[g]``
        ((ngeom,) bool mask; the scene's collision bits allow no other pair). A contact's
        frame has its normal from geom1 to geom2 and ``mj_contactForce`` gives the force on
        geom2, so the force on the robot is +frameᵀ f where the block is geom1 and −frameᵀ f
        where it is geom2."""
        n = data.ncon
        if n == 0:
            return _NO_CONTACT
        geom = data.contact.geom[:n]
        block_first = block[geom[:, 0]]
        f = np.zeros((n, 6))
        for i in range(n):
            mujoco.mj_contactForce(model, data, i, f[i])
        frames = data.contact.frame[:n].reshape(n, 3, 3)  # rows: normal, two tangents
        sign = np.where(block_first, 1.0, -1.0)[:, None]
        force = sign * np.einsum("kji,kj->ki", frames, f[:, :3])  # frameᵀ f
        largest = float(np.sqrt(np.max(np.einsum("ki,ki->k", f[:, :3], f[:, :3]))))
        robot_geom = np.where(block_first, geom[:, 1], geom[:, 0])
        return cls(robot_geom, force, sign * frames[:, 0, :], f[:, 0], largest, force.sum(0))

    def of_geom(self, geom: int) -> BlockContacts:
        """The contacts of one robot geom (e.g. the peg)."""
        keep = self.robot_geom == geom
        force = self.force[keep]
        largest = float(np.sqrt(np.max(np.sum(force**2, axis=1)))) if len(force) else 0.0
        return BlockContacts(
            self.robot_geom[keep], force, self.normal[keep], self.pressing[keep], largest,
            force.sum(axis=0),
        )


_NO_CONTACT = BlockContacts(
    np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), 0.0, np.zeros(3)
)


@dataclass(frozen=True)
class ContactFlags:
    """The peg's contact state in the bore (see PegInHole's Episode End).

    Attributes:
        two_point: contacts on the bore's side on opposite sides.
        wedged: two-point contact shallower than μ D (Whitney's wedging condition).
        jammed: two-point contact deeper than μ D while the peg does not advance.
    """

    two_point: bool = False
    wedged: bool = False
    jammed: bool = False


def contact_flags(
    peg: BlockContacts, axis: np.ndarray, depth: float, axial_speed: float, mu_diameter: float
) -> ContactFlags:
    """Two-point contact, wedging and jamming from the peg's contacts.

    Args:
        peg: the peg's contacts with the block.
        axis: (3,) the true bore axis, world frame (out of the hole).
        depth: tip depth in the true hole (m).
        axial_speed: tip speed along the axis (m/s).
        mu_diameter: μ D, the friction coefficient times the hole diameter (m).
    """
    along = peg.normal @ axis  # (k,) n · axis
    side = (np.abs(along) < SIDE_NORMAL) & (peg.pressing > 0)
    if np.count_nonzero(side) < 2:
        return ContactFlags()
    lateral = peg.normal[side] - along[side, None] * axis
    lateral /= np.maximum(np.linalg.norm(lateral, axis=1, keepdims=True), 1e-12)
    cosines = lateral @ lateral.T
    if not np.any(np.triu(cosines < -0.5, k=1)):  # no two side contacts facing each other
        return ContactFlags()
    wedged = depth < mu_diameter
    return ContactFlags(True, wedged, not wedged and abs(axial_speed) < STALL_SPEED)
