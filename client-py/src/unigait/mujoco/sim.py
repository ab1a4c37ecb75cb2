"""One Go2 in MuJoCo driven like the server drives its robots: explicit PD torques every step.

The server's actuator law (``physics/actuation.rs``): motor torque
``clip(kp (target - q) - kd qdot, +-effort)`` computed from the state at the start of each
5 ms physics step and held over it. Passive joint damping, Coulomb friction and armature are the
model's (:mod:`unigait.mujoco.model`). Conventions as the server: world z up, quaternions here
are (w, x, y, z) (MuJoCo's), velocities of the base are its origin's, in the world frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from unigait.mujoco.model import Go2Model

CONTACT_FORCE_N = 1.0
"""A contact counts above this normal force (N): the task's ``rewards.contact_threshold``."""


@dataclass
class Go2State:
    """The measured state of the robot (world frame unless noted).

    Attributes:
        base_pos: float [3] trunk origin (m).
        base_quat: float [4] trunk orientation (w, x, y, z).
        base_linvel: float [3] velocity of the trunk origin (m/s).
        base_angvel: float [3] trunk angular velocity (rad/s), world frame.
        q: float [12] joint angles (rad), action order.
        qd: float [12] joint speeds (rad/s).
        foot_pos: float [4, 3] foot sphere centres (m).
        foot_force: float [4] normal contact force on each foot (N).
        trunk_force: Normal contact force on the trunk (N).
        head_force: Normal contact force on the head (N).
        leg_contacts: Contacts of other leg parts (hips, thighs, calves) with the floor.
    """

    base_pos: np.ndarray
    base_quat: np.ndarray
    base_linvel: np.ndarray
    base_angvel: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    foot_pos: np.ndarray
    foot_force: np.ndarray
    trunk_force: float
    head_force: float
    leg_contacts: int

    @property
    def rotation(self) -> np.ndarray:
        """float [3, 3] trunk rotation matrix (base frame -> world)."""
        return quat_to_matrix(self.base_quat)


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z).

    Args:
        quat: float [4].

    Returns:
        float [3, 3].
    """
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, np.asarray(quat, dtype=np.float64))
    return mat.reshape(3, 3)


def euler_roll(quat: np.ndarray) -> float:
    """Euler roll (XYZ convention, legged_gym's ``get_euler_xyz``) of (w, x, y, z)."""
    w, x, y, z = (float(v) for v in quat)
    return math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))


def euler_pitch(quat: np.ndarray) -> float:
    """Euler pitch (XYZ convention, positive nose down) of (w, x, y, z), in [-pi/2, pi/2]."""
    w, x, y, z = (float(v) for v in quat)
    return math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))


def euler_yaw(quat: np.ndarray) -> float:
    """Euler yaw (XYZ convention) of (w, x, y, z)."""
    w, x, y, z = (float(v) for v in quat)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class Go2Sim:
    """One robot in MuJoCo, stepped at the model's ``dt`` with the server's PD law.

    Args:
        go2: The compiled model (:func:`unigait.mujoco.model.build_model`).
    """

    def __init__(self, go2: Go2Model) -> None:
        self.go2 = go2
        self.model = go2.model
        self.data = mujoco.MjData(self.model)
        o = go2.options
        self.kp = np.full(12, o.kp)
        self.kd = np.full(12, o.kd)
        self.torques = np.zeros(12)
        self._force6 = np.zeros(6)

    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return float(self.data.time)

    def set_state(
        self,
        q: np.ndarray,
        base_pos: np.ndarray | None = None,
        base_quat: np.ndarray | None = None,
        base_linvel: np.ndarray | None = None,
        base_angvel: np.ndarray | None = None,
        qd: np.ndarray | None = None,
    ) -> None:
        """Teleport the robot (the server's ``set_robot_state``; joint speeds zero by default).

        Args:
            q: float [12] joint angles (rad).
            base_pos: float [3] trunk origin (m); ignored for a fixed base.
            base_quat: float [4] (w, x, y, z); identity by default.
            base_linvel: float [3] velocity of the trunk origin, world frame (m/s).
            base_angvel: float [3] angular velocity, world frame (rad/s).
            qd: float [12] joint speeds (rad/s).
        """
        d = self.data
        mujoco.mj_resetData(self.model, d)
        if self.go2.free:
            quat = np.array([1.0, 0.0, 0.0, 0.0]) if base_quat is None else np.asarray(base_quat)
            d.qpos[0:3] = np.zeros(3) if base_pos is None else base_pos
            d.qpos[3:7] = quat / np.linalg.norm(quat)
            # Free joint: linear velocity of the body origin in the world frame, angular
            # velocity in the body frame.
            if base_linvel is not None:
                d.qvel[0:3] = base_linvel
            if base_angvel is not None:
                d.qvel[3:6] = quat_to_matrix(d.qpos[3:7]).T @ np.asarray(base_angvel)
        d.qpos[self.go2.qpos_adr] = q
        if qd is not None:
            d.qvel[self.go2.dof_adr] = qd
        mujoco.mj_forward(self.model, d)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint angles and speeds, float [12] each."""
        return (
            self.data.qpos[self.go2.qpos_adr].copy(),
            self.data.qvel[self.go2.dof_adr].copy(),
        )

    def step(self, targets: np.ndarray) -> np.ndarray:
        """One physics step towards joint ``targets`` (rad, float [12], not clamped).

        Returns:
            float [12] the motor torques applied over the step (N m).
        """
        q, qd = self.joint_state()
        tau = np.clip(self.kp * (targets - q) - self.kd * qd, -self.go2.effort, self.go2.effort)
        self.data.qfrc_applied[self.go2.dof_adr] = tau
        mujoco.mj_step(self.model, self.data)
        self.torques = tau
        return tau

    def state(self) -> Go2State:
        """The measured state after the last step, contact forces included."""
        m, d = self.model, self.data
        if self.go2.free:
            pos = d.qpos[0:3].copy()
            quat = d.qpos[3:7].copy()
            linvel = d.qvel[0:3].copy()
            angvel = quat_to_matrix(quat) @ d.qvel[3:6]
        else:
            base = m.body("base").id
            pos = d.xpos[base].copy()
            quat = d.xquat[base].copy()
            linvel = np.zeros(3)
            angvel = np.zeros(3)
        q, qd = self.joint_state()
        foot_force = np.zeros(4)
        trunk = head = 0.0
        legs = 0
        feet = {int(g): i for i, g in enumerate(self.go2.foot_geoms)}
        for i in range(d.ncon):
            c = d.contact[i]
            mujoco.mj_contactForce(m, d, i, self._force6)
            normal = abs(float(self._force6[0]))
            for g in (int(c.geom1), int(c.geom2)):
                if g in feet:
                    foot_force[feet[g]] += normal
                elif g in self.go2.trunk_geoms:
                    trunk += normal
                elif g in self.go2.head_geoms:
                    head += normal
                elif self.go2.geom_role.get(g) == "leg":
                    legs += int(normal > CONTACT_FORCE_N)
        return Go2State(
            base_pos=pos,
            base_quat=quat,
            base_linvel=linvel,
            base_angvel=angvel,
            q=q,
            qd=qd,
            foot_pos=d.geom_xpos[self.go2.foot_geoms].copy(),
            foot_force=foot_force,
            trunk_force=trunk,
            head_force=head,
            leg_contacts=legs,
        )

    def total_mass(self) -> float:
        """Mass of the robot (kg)."""
        return float(self.model.body_mass.sum())

    def whole_body_inertia(self, axis: np.ndarray) -> float:
        """Rigid inertia (kg m^2) of the robot about world ``axis`` through its centre of mass.

        Args:
            axis: float [3] unit vector.
        """
        m, d = self.model, self.data
        mass = m.body_mass[1:]
        com = (mass[:, None] * d.xipos[1:]).sum(0) / mass.sum()
        total = 0.0
        for b in range(1, m.nbody):
            rot = d.ximat[b].reshape(3, 3)
            local = rot.T @ axis
            arm = np.cross(axis, d.xipos[b] - com)
            total += float(local @ (m.body_inertia[b] * local)) + float(m.body_mass[b] * arm @ arm)
        return total
