"""The elastic-joint model of ElasticJointTracking: each transmission a rotor and a spring.

Chapter 4's elastic joint: a motor (rotor inertia reflected to the link side, N² J_m) and the
link, coupled by a spring of stiffness k_el. In MuJoCo each joint becomes two hinges
(``motor<i>`` on a massless rotor body, ``joint<i>`` on the link) and a fixed tendon θ − q
with stiffness k_el (θ the motor angle in link units, q_m = N θ).
"""

from __future__ import annotations

import mujoco
import numpy as np

from cir_gym.robot import robot_path

#: Joint stiffness k_el (N m/rad) per joint — an ASSUMPTION of harmonic-drive order of magnitude
#: (the data sheet publishes none), scaled down toward the wrist where the links are light.
DEFAULT_STIFFNESS = (4000.0, 4000.0, 2000.0, 2000.0, 1000.0, 300.0, 300.0)
#: Softest joint spring accepted (N m/rad): gravity alone deflects a softer one by radians.
MIN_STIFFNESS = 10.0
#: Largest ω Δt allowed for the rotor–spring–link mode (stability needs < 2).
MAX_OMEGA_DT = 1.0
#: Damping ratio of each spring with the link inertia at home (structural damping, small).
SPRING_DAMPING_RATIO = 0.05


def elastic_model(robot: str, stiffness: np.ndarray, timestep: float = 5e-4) -> mujoco.MjModel:
    """The robot with a motor joint behind each link joint, coupled by a fixed-tendon spring.

    For joint i a massless rotor body sits on the parent link, coaxial with the link joint;
    its hinge ``motor<i>`` carries the reflected rotor inertia (armature) and the actuator;
    the fixed tendon ``spring<i>`` of length θ_i − q_i (θ the motor angle divided by the gear
    ratio, i.e. in link units) has stiffness k_el,i, so the link feels τ = k_el (θ − q).
    """
    spec = mujoco.MjSpec.from_file(str(robot_path(robot)))
    spec.option.timestep = timestep
    n = len(stiffness)
    for i in range(1, n + 1):
        link = spec.body(f"link{i}")
        joint = spec.joint(f"joint{i}")
        rotor = link.parent.add_body(
            name=f"rotor{i}",
            pos=link.pos,
            quat=link.quat,
            mass=1e-6,
            inertia=[1e-9] * 3,
            explicitinertial=True,
        )
        rotor.add_joint(
            name=f"motor{i}",
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=[0, 0, 1],
            armature=joint.armature,
        )
        joint.armature = 0.0
        spring = spec.add_tendon(
            name=f"spring{i}", stiffness=float(stiffness[i - 1]), springlength=[0.0, 0.0]
        )
        spring.wrap_joint(f"motor{i}", 1.0)
        spring.wrap_joint(f"joint{i}", -1.0)
        spec.actuator(f"motor{i}").target = f"motor{i}"
    for key in spec.keys:  # keyframes would need the motor joints too
        spec.delete(key)
    return spec.compile()
