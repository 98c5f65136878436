"""The shipped robot files pinned to their specification.

iiwa14: the KUKA LBR iiwa 14 R820 data sheet (joint ranges, maximum speeds and torques) and the
Drake/Menagerie link masses, as collected in the course's reference notes on the iiwa14 and cited
in the comment at the top of ``cir_gym/assets/robots/iiwa14.xml``; plus what the environments
need from the file (flange and tcp sites, a flange force/torque sensor, an eye-in-hand camera,
primitive geometry only). planar2r and planar3r: the joint layout of their XML comments.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from cir_gym.robot import Robot, load_model

HINGE = int(mujoco.mjtJoint.mjJNT_HINGE)

# KUKA LBR iiwa 14 R820 data sheet, axes A1..A7
IIWA_RANGE_DEG = (170, 120, 170, 120, 170, 120, 175)
IIWA_SPEED_DEG_S = (85, 85, 100, 75, 130, 135, 135)
IIWA_TORQUE_NM = (320, 320, 176, 176, 110, 40, 40)
# Drake iiwa14 URDF (MuJoCo Menagerie kuka_iiwa_14), links 1..7
IIWA_LINK_MASS_KG = (5.76, 6.35, 3.5, 3.5, 3.5, 1.8, 1.2)


@pytest.fixture(scope="module")
def iiwa() -> mujoco.MjModel:
    return load_model("iiwa14")


def _joint_names(model: mujoco.MjModel) -> list[str]:
    return [model.joint(j).name for j in range(model.njnt)]


def test_iiwa14_has_seven_hinges_about_z_with_the_data_sheet_ranges(iiwa):
    assert iiwa.njnt == iiwa.nq == iiwa.nv == 7
    assert _joint_names(iiwa) == [f"joint{i}" for i in range(1, 8)]
    assert np.all(iiwa.jnt_type == HINGE)
    np.testing.assert_array_equal(iiwa.jnt_axis, np.tile([0.0, 0.0, 1.0], (7, 1)))
    assert np.all(iiwa.jnt_limited)
    limit = np.deg2rad(IIWA_RANGE_DEG)
    np.testing.assert_allclose(iiwa.jnt_range, np.column_stack([-limit, limit]), rtol=1e-15)


def test_iiwa14_actuators_are_joint_motors_with_the_data_sheet_torques(iiwa):
    assert iiwa.nu == 7
    np.testing.assert_array_equal(iiwa.actuator_trntype, int(mujoco.mjtTrn.mjTRN_JOINT))
    np.testing.assert_array_equal(iiwa.actuator_trnid[:, 0], np.arange(7))  # motor i -> joint i
    np.testing.assert_array_equal(iiwa.actuator_gear[:, 0], 1.0)
    assert np.all(iiwa.actuator_ctrllimited)
    torque = np.array(IIWA_TORQUE_NM, dtype=float)
    np.testing.assert_array_equal(iiwa.actuator_ctrlrange, np.column_stack([-torque, torque]))
    np.testing.assert_array_equal(Robot(iiwa).torque_limit, torque)


def test_iiwa14_velocity_limit_is_the_data_sheet_speed(iiwa):
    robot = Robot(iiwa)
    np.testing.assert_allclose(robot.velocity_limit, np.deg2rad(IIWA_SPEED_DEG_S), rtol=1e-15)


def test_iiwa14_link_masses_and_armature(iiwa):
    masses = [iiwa.body(f"link{i}").mass[0] for i in range(1, 8)]
    np.testing.assert_array_equal(masses, IIWA_LINK_MASS_KG)
    assert iiwa.body("payload").mass[0] == 0.0  # set at run time for an unknown payload
    robot = Robot(iiwa)
    # armature is the reflected rotor inertia N² J_m (assumed N and J_m, see the XML comment)
    np.testing.assert_allclose(
        iiwa.dof_armature, robot.gear_ratio**2 * robot.rotor_inertia, rtol=1e-12
    )


def test_iiwa14_flange_tcp_sensor_and_camera(iiwa):
    link7 = iiwa.body("link7").id
    for site, z in (("flange", 0.045), ("tcp", 0.145)):
        assert iiwa.site(site).bodyid[0] == link7
        np.testing.assert_allclose(iiwa.site(site).pos, [0.0, 0.0, z])
    data = mujoco.MjData(iiwa)
    mujoco.mj_forward(iiwa, data)  # q = 0: the arm stands straight up
    np.testing.assert_allclose(data.site("flange").xpos, [0.0, 0.0, 1.306], atol=1e-12)

    sensors = {int(iiwa.sensor_type[s]): s for s in range(iiwa.nsensor)}
    force, torque = int(mujoco.mjtSensor.mjSENS_FORCE), int(mujoco.mjtSensor.mjSENS_TORQUE)
    assert force in sensors and torque in sensors
    for kind in (force, torque):
        sensor = sensors[kind]
        assert iiwa.sensor_objtype[sensor] == int(mujoco.mjtObj.mjOBJ_SITE)
        assert iiwa.sensor_dim[sensor] == 3
        ft_site = int(iiwa.sensor_objid[sensor])
        np.testing.assert_allclose(data.site_xpos[ft_site], data.site("flange").xpos, atol=1e-12)

    camera = iiwa.camera("flange_cam")
    assert camera.bodyid[0] == link7
    np.testing.assert_allclose(camera.pos, iiwa.site("flange").pos)
    # a camera looks along its own −z: here along link7's +z, away from the arm
    view = -data.cam_xmat[camera.id].reshape(3, 3)[:, 2]
    np.testing.assert_allclose(view, data.xmat[link7].reshape(3, 3)[:, 2], atol=1e-12)


@pytest.mark.parametrize("name", ["iiwa14", "planar2r", "planar3r"])
def test_geometry_is_primitive_only(name):
    model = load_model(name)
    assert model.nmesh == 0
    assert not np.any(model.geom_type == int(mujoco.mjtGeom.mjGEOM_MESH))


@pytest.mark.parametrize(
    ("name", "n", "axis"),
    [
        # planar3r moves in the horizontal x-y plane; planar2r in the vertical x-z plane (so that
        # gravity acts, as in the textbook example), about −y: positive q lifts the link.
        ("planar3r", 3, [0.0, 0.0, 1.0]),
        ("planar2r", 2, [0.0, -1.0, 0.0]),
    ],
)
def test_planar_arms_have_parallel_hinges(name, n, axis):
    model = load_model(name)
    assert model.njnt == model.nq == model.nv == model.nu == n
    assert _joint_names(model) == [f"joint{i}" for i in range(1, n + 1)]
    assert np.all(model.jnt_type == HINGE)
    np.testing.assert_array_equal(model.jnt_axis, np.tile(axis, (n, 1)))
    np.testing.assert_array_equal(model.body_quat[1:], np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)))
    robot = Robot(model)
    assert robot.n == n and "ee" in [model.site(i).name for i in range(model.nsite)]
    np.testing.assert_allclose(
        model.dof_armature, robot.gear_ratio**2 * robot.rotor_inertia, rtol=1e-12
    )
