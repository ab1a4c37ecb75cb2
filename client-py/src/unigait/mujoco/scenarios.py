"""The physics cross-check scenarios, run in MuJoCo.

Each function mirrors the scenario of the same name in ``tools/crosscheck/src/main.rs``
(same initial state, same target sequence, same measures) and returns the same keys. Shared
definitions: physics step 5 ms, targets held for 4 steps where a policy would set them, joints
in action order (FL, FR, RL, RR x hip, thigh, calf), the robot level at rest at the start.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from unigait.mujoco.model import DEFAULT_Q, PhysicsOptions, build_model
from unigait.mujoco.sim import CONTACT_FORCE_N, Go2Sim, euler_pitch, euler_roll, euler_yaw

DECIMATION = 4
"""Physics steps per policy step."""

STEP_RAD = 0.3
"""Target step of the step-response scenarios (rad)."""
TROT_PERIOD_S = 0.3
TROT_THIGH_AMPLITUDE = 0.25
TROT_CALF_AMPLITUDE = 0.5
TROT_FORWARD_PHASE = 1.25 * math.pi
"""Calf phase of the open-loop trot that walks forward (0.26 m/s in MuJoCo)."""
TROT_BACKWARD_PHASE = 0.5 * math.pi
"""Calf phase of the open-loop trot that walks backward (-0.34 m/s in MuJoCo)."""

Result = dict[str, Any]


def _sim(options: PhysicsOptions, **changes: Any) -> Go2Sim:
    return Go2Sim(build_model(dataclasses.replace(options, **changes)))


def standing_base_z(sim: Go2Sim, gap: float = 0.002) -> float:
    """Base height that puts the lowest foot sole ``gap`` above the floor (level, default pose).

    Args:
        sim: A free-base simulation (its state is overwritten).
        gap: Clearance (m).
    """
    sim.set_state(DEFAULT_Q, base_pos=np.zeros(3))
    s = sim.state()
    return gap - float(np.min(s.foot_pos[:, 2] - sim.go2.foot_radius))


def robot(options: PhysicsOptions) -> Result:
    """The model as simulated: mass, foot positions at the default pose, whole-body inertia."""
    sim = _sim(options)
    sim.set_state(DEFAULT_Q, base_pos=np.array([0.0, 0.0, 1.0]))
    feet = sim.state().foot_pos - np.array([0.0, 0.0, 1.0])
    inertia = [sim.whole_body_inertia(np.eye(3)[k]) for k in range(3)]
    return {
        "default_q": DEFAULT_Q.tolist(),
        "effort": sim.go2.effort.tolist(),
        "kp": options.kp,
        "kd": options.kd,
        "armature": options.armature,
        "joint_damping": options.joint_damping,
        "joint_friction": options.joint_friction,
        "min_link_inertia": options.min_link_inertia,
        "dt": options.dt,
        "mass_kg": sim.total_mass(),
        "foot_pos_default": feet.tolist(),
        "foot_radius": sim.go2.foot_radius.tolist(),
        "whole_body_inertia": inertia,
        "standing_base_z": standing_base_z(sim),
    }


def _crossing_time(trace: np.ndarray, level: float, dt: float) -> float:
    prev = 0.0
    for i, v in enumerate(trace):
        if v >= level:
            frac = (level - prev) / (v - prev) if v > prev else 1.0
            return dt * (i + frac)
        prev = float(v)
    return math.nan


def step_response(options: PhysicsOptions, joint: int, steps: int = 200) -> Result:
    """FL ``joint`` (0 hip, 1 thigh, 2 calf) answering a 0.3 rad target step, trunk welded at 1 m.

    Returns:
        rise_time_s (10% to 90% of the step, interpolated), overshoot (peak beyond the target,
        as a fraction of the step), peak_time_s, settled_error_rad (target minus the mean of the
        last 0.2 s), q (the joint's trace, one value per physics step).
    """
    sim = _sim(options, fixed_base_height=1.0)
    sim.set_state(DEFAULT_Q)
    targets = DEFAULT_Q.copy()
    targets[joint] += STEP_RAD
    trace = np.empty(steps)
    for i in range(steps):
        sim.step(targets)
        trace[i] = sim.data.qpos[sim.go2.qpos_adr[joint]]
    rel = (trace - DEFAULT_Q[joint]) / STEP_RAD
    dt = options.dt
    settled = float(trace[-40:].mean())
    peak_i = int(np.argmax(rel))
    return {
        "params": {"joint": joint, "step_rad": STEP_RAD, "steps": steps, "trunk_height_m": 1.0},
        "rise_time_s": _crossing_time(rel, 0.9, dt) - _crossing_time(rel, 0.1, dt),
        "overshoot": float(rel[peak_i] - 1.0),
        "peak_time_s": dt * (peak_i + 1),
        "settled_error_rad": float(targets[joint] - settled),
        "q": trace.tolist(),
    }


def stand(options: PhysicsOptions, steps: int = 800, tail: int = 200) -> Result:
    """4 s at the default pose on flat ground, feet released 2 mm above it.

    Returns:
        base_height_m, base_x_m, pitch_rad, roll_rad, foot_force_n [4] and total_foot_force_n,
        means over the last ``tail`` steps; base_height_trace (one value per policy step).
    """
    sim = _sim(options)
    z0 = standing_base_z(sim)
    sim.set_state(DEFAULT_Q, base_pos=np.array([0.0, 0.0, z0]))
    acc = np.zeros(4 + 4)
    heights = []
    for i in range(steps):
        sim.step(DEFAULT_Q)
        s = sim.state()
        if i % DECIMATION == DECIMATION - 1:
            heights.append(float(s.base_pos[2]))
        if i >= steps - tail:
            acc[:4] += [
                s.base_pos[2],
                s.base_pos[0],
                euler_pitch(s.base_quat),
                euler_roll(s.base_quat),
            ]
            acc[4:] += s.foot_force
    acc /= tail
    return {
        "params": {"steps": steps, "tail_steps": tail, "initial_base_z": z0},
        "base_height_m": float(acc[0]),
        "base_x_m": float(acc[1]),
        "pitch_rad": float(acc[2]),
        "roll_rad": float(acc[3]),
        "foot_force_n": acc[4:].tolist(),
        "total_foot_force_n": float(acc[4:].sum()),
        "base_height_trace": heights,
    }


def drop(
    options: PhysicsOptions,
    steps: int = 600,
    height: float = 0.5,
    tail: int = 100,
    band: float = 0.005,
) -> Result:
    """Released at rest with the base level at ``height``, the default joints held.

    Returns:
        first_contact_s (a foot above 1 N), peak_foot_force_n (total foot force averaged over
        each policy step, highest), peak_trunk_force_n, min_base_height_m (after the first
        contact), settled_height_m (mean of the last ``tail`` steps), settle_time_s (after it
        the base stays within ``band`` of the settled height), base_height_trace.
    """
    sim = _sim(options)
    sim.set_state(DEFAULT_Q, base_pos=np.array([0.0, 0.0, height]))
    z = np.empty(steps)
    total = np.empty(steps)
    trunk_peak = 0.0
    for i in range(steps):
        sim.step(DEFAULT_Q)
        s = sim.state()
        z[i] = s.base_pos[2]
        total[i] = s.foot_force.sum()
        trunk_peak = max(trunk_peak, s.trunk_force)
    touching = np.nonzero(total > CONTACT_FORCE_N)[0]
    first = int(touching[0]) if touching.size else None
    peak = float(total[: steps // DECIMATION * DECIMATION].reshape(-1, DECIMATION).mean(1).max())
    final = float(z[-tail:].mean())
    outside = np.nonzero(np.abs(z - final) > band)[0]
    settle = (int(outside[-1]) + 1) * options.dt if outside.size else 0.0
    return {
        "params": {
            "steps": steps,
            "base_height_m": height,
            "tail_steps": tail,
            "settle_band_m": band,
        },
        "first_contact_s": (first + 1) * options.dt if first is not None else math.nan,
        "peak_foot_force_n": peak,
        "peak_trunk_force_n": trunk_peak,
        "min_base_height_m": float(z[first or 0 :].min()),
        "settled_height_m": final,
        "settle_time_s": settle,
        "base_height_trace": z[DECIMATION - 1 :: DECIMATION].tolist(),
    }


def trot_targets(t: float, calf_phase: float) -> np.ndarray:
    """Open-loop trot targets at time ``t`` (s) since the gait began (see crosscheck.rs).

    Per leg, theta = 2 pi t / T + (0 for FL and RR, pi for FR and RL); thigh q0 + A sin theta,
    calf q0 + B cos(theta + ``calf_phase``). The calf phase picks the direction of travel.
    """
    q = DEFAULT_Q.copy()
    for leg in range(4):
        theta = 2.0 * math.pi * t / TROT_PERIOD_S + (math.pi if leg in (1, 2) else 0.0)
        q[3 * leg + 1] += TROT_THIGH_AMPLITUDE * math.sin(theta)
        q[3 * leg + 2] += TROT_CALF_AMPLITUDE * math.cos(theta + calf_phase)
    return q


def trot(
    options: PhysicsOptions,
    calf_phase: float,
    stand_steps: int = 200,
    gait_steps: int = 800,
    measure: int = 600,
) -> Result:
    """1 s standing, then 4 s of open-loop trot targets (changed at 50 Hz); last 3 s measured.

    Returns:
        forward_speed_mps, lateral_speed_mps, yaw_rate_radps (displacement over the measured
        span), base_height_m and pitch_mean_rad (means), roll_range_rad and pitch_range_rad
        (max - min), trace (x, y, z, roll, pitch, yaw per policy step of the gait).
    """
    sim = _sim(options)
    z0 = standing_base_z(sim)
    sim.set_state(DEFAULT_Q, base_pos=np.array([0.0, 0.0, z0]))
    for _ in range(stand_steps):
        sim.step(DEFAULT_Q)
    trace = []
    start = last = sim.state()
    for i in range(gait_steps):
        t_policy = (i // DECIMATION * DECIMATION) * options.dt
        sim.step(trot_targets(t_policy, calf_phase))
        s = sim.state()
        if i + 1 == gait_steps - measure:
            start = s
        if i % DECIMATION == DECIMATION - 1:
            q = s.base_quat
            trace.append([*s.base_pos.tolist(), euler_roll(q), euler_pitch(q), euler_yaw(q)])
        last = s
    span = measure * options.dt
    tail = np.array(trace[-(measure // DECIMATION) :])
    return {
        "params": {
            "stand_steps": stand_steps,
            "gait_steps": gait_steps,
            "measure_steps": measure,
            "period_s": TROT_PERIOD_S,
            "thigh_amplitude_rad": TROT_THIGH_AMPLITUDE,
            "calf_amplitude_rad": TROT_CALF_AMPLITUDE,
            "calf_phase_rad": calf_phase,
        },
        "forward_speed_mps": float(last.base_pos[0] - start.base_pos[0]) / span,
        "lateral_speed_mps": float(last.base_pos[1] - start.base_pos[1]) / span,
        "yaw_rate_radps": (euler_yaw(last.base_quat) - euler_yaw(start.base_quat)) / span,
        "base_height_m": float(tail[:, 2].mean()),
        "roll_range_rad": float(np.ptp(tail[:, 3])),
        "pitch_range_rad": float(np.ptp(tail[:, 4])),
        "pitch_mean_rad": float(tail[:, 4].mean()),
        "trace": trace,
    }


def free_float(
    options: PhysicsOptions,
    joints: list[int],
    delta: float = 0.5,
    steps: int = 100,
    early: int = 10,
) -> Result:
    """No gravity, the robot at rest 1 m up: ``joints`` step by ``delta`` and the trunk turns.

    Returns:
        joint_moved_rad (first joint, after ``steps``), joint_moved_early_rad (after ``early``
        steps: sets the armature apart), roll_rad, pitch_rad, yaw_rad of the trunk at the end,
        trace (joint move, roll, pitch, yaw per physics step).
    """
    sim = _sim(options, gravity=0.0)
    sim.set_state(DEFAULT_Q, base_pos=np.array([0.0, 0.0, 1.0]))
    targets = DEFAULT_Q.copy()
    targets[joints] += delta
    trace = []
    early_move = 0.0
    j = joints[0]
    for i in range(steps):
        sim.step(targets)
        s = sim.state()
        moved = float(s.q[j] - DEFAULT_Q[j])
        if i + 1 == early:
            early_move = moved
        q = s.base_quat
        trace.append([moved, euler_roll(q), euler_pitch(q), euler_yaw(q)])
    return {
        "params": {
            "joints": list(joints),
            "delta_rad": delta,
            "steps": steps,
            "early_steps": early,
        },
        "joint_moved_rad": trace[-1][0],
        "joint_moved_early_rad": early_move,
        "roll_rad": trace[-1][1],
        "pitch_rad": trace[-1][2],
        "yaw_rad": trace[-1][3],
        "trace": trace,
    }


SCENARIOS: dict[str, Callable[[PhysicsOptions], Result]] = {
    "robot": robot,
    "step_hip": lambda o: step_response(o, 0),
    "step_thigh": lambda o: step_response(o, 1),
    "step_calf": lambda o: step_response(o, 2),
    "stand": stand,
    "drop": drop,
    "trot_forward": lambda o: trot(o, TROT_FORWARD_PHASE),
    "trot_backward": lambda o: trot(o, TROT_BACKWARD_PHASE),
    "free_float_roll": lambda o: free_float(o, [0, 6]),
    "free_float_pitch": lambda o: free_float(o, [1, 4, 7, 10]),
}
"""Every physics scenario by name, as the cross-check driver names them."""


def run(names: list[str] | None = None, options: PhysicsOptions | None = None) -> dict[str, Result]:
    """Run the named scenarios (all by default) in MuJoCo.

    Args:
        names: Scenario names (keys of :data:`SCENARIOS`).
        options: Model options; None = the server's nominal setup.
    """
    options = options or PhysicsOptions()
    return {n: SCENARIOS[n](options) for n in (names or list(SCENARIOS))}
