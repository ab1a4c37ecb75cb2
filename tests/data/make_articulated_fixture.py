"""Record MuJoCo's mass matrix and bias forces of our Go2 on a few states (articulated engine).

The Rust test ``server/sim/tests/articulated_vs_mujoco.rs`` rebuilds ``mj_fullM`` and
``qfrc_bias`` with unigait's own reduced-coordinate dynamics from the same states and compares.
The model is ``assets/go2/go2.urdf`` loaded the way :mod:`unigait.mujoco.model` loads it, with
the URDF's own link inertias (``min_link_inertia = 0``: the rapier world's inertia floor is not
part of the robot) and armature 0.02 kg m^2 on each joint (MuJoCo's ``armature``, on the mass
matrix's diagonal), so both sides model the same robot.

States (seeded, so running the script again writes the same file)::

    .venv/bin/python tests/data/make_articulated_fixture.py

- the default pose at rest, level, and then with random velocities;
- random joint angles within the URDF limits, random base orientations, random velocities;
- the biped start, pitched nose down by about pi/2 (and exactly pi/2);
- one far from the world origin (the dynamics must not depend on where the robot is).

MuJoCo's free joint: ``qpos[0:7]`` = base position, unit quaternion (w, x, y, z);
``qvel[0:6]`` = linear velocity of the base origin in the world frame, then the angular
velocity in the base's own frame. The script checks that convention on the model before writing.
"""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
from unigait.mujoco.model import DEFAULT_Q, JOINT_NAMES, PhysicsOptions, build_model

HERE = Path(__file__).resolve().parent
OUT = HERE.parents[1] / "server" / "sim" / "tests" / "data" / "articulated_fixture.json"
ARMATURE = 0.02
GRAVITY = 9.81
SEED = 34


def random_quat(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random unit quaternion (w, x, y, z)."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def pitch_quat(pitch: float, roll: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    """Quaternion (w, x, y, z) of yaw about z, then pitch about y, then roll about x."""
    q = np.zeros(4)
    mujoco.mju_euler2Quat(q, np.array([roll, pitch, yaw]), "xyz")
    return q


def check_free_joint_convention(model: mujoco.MjModel) -> None:
    """Angular qvel in the base frame, linear qvel in the world frame (MuJoCo's free joint)."""
    data = mujoco.MjData(model)
    data.qpos[3:7] = pitch_quat(0.0, roll=1.0)
    data.qvel[:] = 0.0
    data.qvel[5] = 1.0
    mujoco.mj_forward(model, data)
    vel = np.zeros(6)
    mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, 1, vel, 0)
    # Spin about the base's z axis, which roll 1 rad turned to (0, -sin 1, cos 1) in the world.
    assert np.allclose(vel[:3], [0.0, -np.sin(1.0), np.cos(1.0)]), vel
    data.qvel[:] = 0.0
    data.qvel[0] = 1.0
    mujoco.mj_forward(model, data)
    mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_BODY, 1, vel, 0)
    assert np.allclose(vel, [0.0, 0.0, 0.0, 1.0, 0.0, 0.0]), vel


def states(
    model: mujoco.MjModel, rng: np.random.Generator
) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, qpos, qvel) of the recorded states."""
    lo = model.jnt_range[1:, 0]
    hi = model.jnt_range[1:, 1]

    def qpos(pos: list[float], quat: np.ndarray, joints: np.ndarray) -> np.ndarray:
        return np.concatenate([pos, quat, joints])

    def qvel(scale: float = 1.0) -> np.ndarray:
        base_lin = rng.uniform(-1.0, 1.0, 3)
        base_ang = rng.uniform(-2.0, 2.0, 3)
        joints = rng.uniform(-10.0, 10.0, 12)
        return scale * np.concatenate([base_lin, base_ang, joints])

    level = np.array([1.0, 0.0, 0.0, 0.0])
    out = [
        ("default_rest", qpos([0.0, 0.0, 0.32], level, DEFAULT_Q), np.zeros(18)),
        ("default_moving", qpos([0.0, 0.0, 0.32], level, DEFAULT_Q), qvel()),
    ]
    for k in range(4):
        out.append(
            (
                f"random_{k}",
                qpos([*rng.uniform(-1.0, 1.0, 2), 0.4], random_quat(rng), rng.uniform(lo, hi)),
                qvel(),
            )
        )
    out.append(
        ("random_rest", qpos([0.0, 0.0, 0.4], random_quat(rng), rng.uniform(lo, hi)), np.zeros(18))
    )
    for name, pitch in (("biped_pitch_1.5", 1.5), ("biped_pitch_half_pi", np.pi / 2)):
        joints = DEFAULT_Q + rng.uniform(-0.2, 0.2, 12)
        joints = np.clip(joints, lo, hi)
        quat = pitch_quat(pitch, roll=rng.uniform(-0.1, 0.1), yaw=rng.uniform(-np.pi, np.pi))
        out.append((name, qpos([0.0, 0.0, 0.45], quat, joints), qvel()))
    out.append(
        (
            "far_from_origin",
            qpos([50.0, -30.0, 2.0], random_quat(rng), rng.uniform(lo, hi)),
            qvel(),
        )
    )
    return out


def main() -> None:
    """Write the fixture."""
    go2 = build_model(PhysicsOptions(min_link_inertia=0.0, armature=ARMATURE, gravity=GRAVITY))
    model = go2.model
    assert model.nq == 19 and model.nv == 18
    assert [model.joint(j).name for j in range(1, model.njnt)] == list(JOINT_NAMES)
    check_free_joint_convention(model)
    rng = np.random.default_rng(SEED)
    data = mujoco.MjData(model)
    records = []
    for name, qpos, qvel in states(model, rng):
        data.qpos[:] = qpos
        data.qvel[:] = qvel
        data.qfrc_applied[:] = 0.0
        mujoco.mj_forward(model, data)
        full = np.zeros((model.nv, model.nv))
        mujoco.mj_fullM(model, data, full)
        records.append(
            {
                "name": name,
                "qpos": data.qpos.tolist(),
                "qvel": data.qvel.tolist(),
                "mass_matrix": full.flatten().tolist(),
                "bias": data.qfrc_bias.tolist(),
            }
        )
    fixture = {
        "about": "MuJoCo mj_fullM and qfrc_bias of assets/go2/go2.urdf; "
        "written by tests/data/make_articulated_fixture.py",
        "mujoco_version": mujoco.__version__,
        "armature": ARMATURE,
        "gravity": GRAVITY,
        "nv": model.nv,
        "joint_names": list(JOINT_NAMES),
        "states": records,
    }
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(fixture, indent=1) + "\n")
    print(f"wrote {len(records)} states to {OUT} ({OUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
