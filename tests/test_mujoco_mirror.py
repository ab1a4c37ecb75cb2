"""The mirror maps against physics: a mirrored Go2, driven by mirrored actions, stays the mirror.

The learner's mirror loss (decision record 0033) assumes that the maps of
``unigait.algorithms.symmetry`` are the robot's left-right symmetry: that o_t and e_t of the
mirrored robot are the mapped o_t and e_t. This test builds both robots in MuJoCo from our URDF,
tilted, turning and moving sideways, with every joint off its default, steps them with
random actions and their mirrors, and compares what each observes. It catches a wrong sign (a
hip, the roll measure, an angular-velocity component) or a wrong leg swap, and an asymmetric
URDF.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco", reason="the MuJoCo tests need the `mujoco` extra")

from unigait.algorithms.symmetry import FOOT_SWAP, ActorMirror, tensor_mirror
from unigait.client import Spec
from unigait.mujoco.model import DEFAULT_Q, PhysicsOptions, build_model
from unigait.mujoco.observation import QUAD, ObservationInputs, TaskSettings, build_observation
from unigait.mujoco.sim import Go2Sim, Go2State

LEGS, LEG_JOINTS = ("FL", "FR", "RL", "RR"), ("hip", "thigh", "calf")
JOINTS = tuple(f"{leg}_{j}_joint" for leg in LEGS for j in LEG_JOINTS)
FLIP_Y = np.diag([1.0, -1.0, 1.0])


def spec() -> Spec:
    """A spec with the server's o_t and e_t layout (the tensors' fields are what matters)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "client-py" / "tests"))
    from fakes import proto_spec

    msg = proto_spec(1)
    del msg.joint_names[:]
    msg.joint_names.extend(JOINTS)
    return Spec.from_proto(msg)


def mirrored_quat(q: np.ndarray) -> np.ndarray:
    """The orientation S R S with S = diag(1, -1, 1): (w, x, y, z) -> (w, -x, y, -z)."""
    return np.array([q[0], -q[1], q[2], -q[3]])


def observe(sim: Go2Sim, action: np.ndarray, command: np.ndarray, step: int) -> np.ndarray:
    """o_t (without noise) and e_t's velocity, contacts and foot heights, concatenated."""
    s: Go2State = sim.state()
    inputs = ObservationInputs(
        base_quat=s.base_quat,
        base_angvel_body=s.rotation.T @ s.base_angvel,
        q=s.q,
        qd=s.qd,
        last_action=action,
        command=command,
        mode=QUAD,
        episode_step=step,
    )
    o = build_observation(inputs, TaskSettings())
    velocity = s.rotation.T @ s.base_linvel
    contact = (s.foot_force > 1.0).astype(np.float64)
    e = np.concatenate([velocity, contact, [0.0, 0.0, 1.0], s.foot_pos[:, 2]])
    return np.concatenate([o, e])


def test_a_mirrored_robot_driven_by_mirrored_actions_stays_the_mirror() -> None:
    mirror = ActorMirror.from_spec(spec(), 1)
    obs_map = tensor_mirror(spec(), "obs")
    act = mirror.actions
    rng = np.random.default_rng(7)
    go2 = build_model(PhysicsOptions())
    left, right = Go2Sim(go2), Go2Sim(go2)
    q0 = DEFAULT_Q + rng.uniform(-0.2, 0.2, 12)
    quat = np.array([np.cos(0.1), 0.3 * np.sin(0.1), 0.2 * np.sin(0.1), 0.9 * np.sin(0.1)])
    quat /= np.linalg.norm(quat)
    pos, lin = np.array([0.0, 0.1, 0.36]), np.array([0.3, 0.2, 0.0])
    ang = np.array([0.2, -0.1, 0.4])
    left.set_state(q0, pos, quat, lin, ang)
    # the mirrored joint angles: the map holds for offsets from the (symmetric) defaults
    q0_mirror = DEFAULT_Q + act(torch.from_numpy(q0 - DEFAULT_Q)).numpy()
    # world vectors reflect (y flips); the angular velocity is a pseudovector: -S w
    right.set_state(q0_mirror, FLIP_Y @ pos, mirrored_quat(quat), FLIP_Y @ lin, -FLIP_Y @ ang)
    command = np.array([0.4, 0.2, 0.3])
    command_mirror = np.array([0.4, -0.2, -0.3])
    action = np.zeros(12)
    worst = 0.0
    for step in range(60):
        a = rng.normal(0.0, 0.5, 12)
        a_mirror = act(torch.from_numpy(a)).numpy()
        for _ in range(4):
            left.step(DEFAULT_Q + 0.25 * a)
            right.step(DEFAULT_Q + 0.25 * a_mirror)
        action = a
        x = observe(left, action, command, step)
        y = observe(right, a_mirror, command_mirror, step)
        o_x, o_y = torch.from_numpy(x[:53]), torch.from_numpy(y[:53])
        expected = obs_map(o_x)
        clock = spec().obs.slice("clock")
        # both robots keep one clock here; the map's swap is checked on its own below
        expected[clock] = o_y[clock]
        worst = max(worst, float((expected - o_y).abs().max()))
        e_x, e_y = x[53:], y[53:]
        np.testing.assert_allclose(e_y[:3], e_x[:3] * [1, -1, 1], atol=1e-3)
        np.testing.assert_array_equal(e_y[3:7], e_x[3:7][list(FOOT_SWAP)])
        np.testing.assert_allclose(e_y[10:], e_x[10:][list(FOOT_SWAP)], atol=1e-4)
    # 60 policy steps of contact dynamics: the robots agree to float rounding and the solver
    assert worst < 1e-3, worst
    # the robot did something: it moved off the spawn state and touched the ground
    assert np.abs(left.state().q - q0).max() > 0.1


def test_the_clock_swap_is_the_gait_half_a_cycle_later() -> None:
    """Swapping FL/FR and RL/RR in the trot's clocks is the clock at phase + 1/2."""
    from unigait.mujoco.observation import gait_clock

    settings = TaskSettings(gait_period_s=0.4)  # 20 policy steps, so half a cycle is 10
    for step in range(0, 40, 3):
        now = gait_clock(settings, step, QUAD)
        later = gait_clock(settings, step + 10, QUAD)
        np.testing.assert_allclose(now[list(FOOT_SWAP)], later, atol=1e-5)
