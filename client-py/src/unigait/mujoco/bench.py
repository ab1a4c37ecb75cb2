"""MuJoCo's side of the simulation benchmark: the server's bench loop, in MuJoCo, one JSON line.

The loop is ``unigait-server bench --actions random --physics-only``'s: N Go2s on flat ground,
dt 5 ms, decimation 4, PD kp 20 / kd 0.5 towards joint targets drawn each policy step as the
default pose + U(-0.25, 0.25) rad per joint, a robot that falls put back at its start state.
MuJoCo runs it the way a MuJoCo user would run it fast on a CPU: the PD law as MuJoCo position
actuators (so no Python between physics steps) and ``mujoco.rollout`` stepping the whole batch in
C, one call per policy step. Two solver settings:

- ``default``: the model as :func:`unigait.mujoco.model.build_model` builds it for the physics
  cross-checks (Newton, elliptic cone, impratio 100, 100 iterations; MuJoCo's defaults otherwise);
- ``playground``: MuJoCo Playground's training settings for legged robots (pyramidal cone,
  1 solver iteration, 5 line-search iterations), on the same model.

A robot counts as fallen when its trunk origin is below 0.15 m or its up axis tilts past 60
degrees, as in the server's ``bench --reference-loop``.

Each record also gives MuJoCo's own stage timers (``mjData.timer``, always on in MuJoCo 4) in
microseconds per robot physics step. :func:`compare` runs the server's bench too (with and
without the robots' joints) and :func:`tables` prints both engines' stages side by side.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import time
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
from mujoco import rollout

from unigait.mujoco.model import DEFAULT_Q, PhysicsOptions, build_model

SOLVERS: dict[str, dict[str, Any]] = {
    "default": {},
    "playground": {"cone": "pyramidal", "iterations": 1, "ls_iterations": 5, "impratio": 1.0},
}
"""Solver settings by name: overrides of :class:`PhysicsOptions`."""

DECIMATION = 4
"""Physics steps per policy step (the task's)."""

ACTION_RANGE_RAD = 0.25
"""Random joint targets: default pose +- this (the server bench's ``--actions random``)."""

START_HEIGHT_M = 0.33
"""Trunk height of the start state (feet just above the ground at the default pose)."""

TIMERS: tuple[str, ...] = (
    "step",
    "forward",
    "position",
    "pos_kinematics",
    "pos_inertia",
    "pos_collision",
    "col_broadphase",
    "col_narrowphase",
    "pos_make",
    "pos_project",
    "velocity",
    "actuation",
    "constraint",
    "advance",
)
"""MuJoCo's timers reported, by ``mjTIMERSTRING`` name (``inverse`` is never run here)."""


def _timer_seconds(data: mujoco.MjData) -> dict[str, float]:
    """Every timer's accumulated duration (s), by name."""
    names = list(mujoco.mjTIMERSTRING)
    return {name: float(data.timer[names.index(name)].duration) for name in TIMERS}


def stage_micros(timers: dict[str, float], wall_s: float, robot_steps: int) -> dict[str, float]:
    """MuJoCo's stages in microseconds per robot physics step, with the derived remainders.

    Args:
        timers: Seconds per timer name over the timed steps (:data:`TIMERS`).
        wall_s: Wall time of the timed ``rollout`` calls (s).
        robot_steps: Robot physics steps they ran.

    Returns:
        Each timer, plus ``forward_other`` (forward outside position, velocity, actuation and
        constraint: the acceleration, sensors, energy), ``step_other`` (step outside forward and
        advance: state checks) and ``outside_step`` (the rollout's own work: state copies).
    """
    us = {name: seconds * 1e6 / robot_steps for name, seconds in timers.items()}
    parts = ("position", "velocity", "actuation", "constraint")
    us["forward_other"] = us["forward"] - sum(us[p] for p in parts)
    us["step_other"] = us["step"] - us["forward"] - us["advance"]
    us["wall"] = wall_s * 1e6 / robot_steps
    us["outside_step"] = us["wall"] - us["step"]
    return us


def run(envs: int, steps: int, solver: str, seed: int = 0, warmup: int = 20) -> dict[str, Any]:
    """Time ``steps`` policy steps of ``envs`` robots on one thread.

    Args:
        envs: Batch size.
        steps: Policy steps timed (after ``warmup`` untimed ones).
        solver: A key of :data:`SOLVERS`.
        seed: Seed of the random targets.
        warmup: Untimed policy steps first.

    Returns:
        The JSON record: env and physics steps/s, the solver settings, resets.
    """
    options = dataclasses.replace(PhysicsOptions(), position_actuators=True, **SOLVERS[solver])
    go2 = build_model(options)
    model = go2.model
    data = mujoco.MjData(model)
    qpos_adr = go2.qpos_adr
    data.qpos[0:3] = [0.0, 0.0, START_HEIGHT_M]
    data.qpos[3:7] = [1.0, 0.0, 0.0, 0.0]
    data.qpos[qpos_adr] = DEFAULT_Q
    data.ctrl[:] = DEFAULT_Q
    mujoco.mj_forward(model, data)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    start = np.zeros(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, start, spec)
    state = np.tile(start, (envs, 1))
    rng = np.random.default_rng(seed)
    # State layout (mjSTATE_FULLPHYSICS): time, qpos, qvel, act, ... -> qpos starts at 1.
    z_col, quat_cols = 1 + 2, slice(1 + 3, 1 + 7)
    resets = 0
    physics_steps = 0
    timed = 0.0
    step_timer = list(mujoco.mjTIMERSTRING).index("step")
    timers_before, steps_before = _timer_seconds(data), 0
    for step in range(warmup + steps):
        if step == warmup:
            # rollout adds every robot's steps to this one MjData's timers.
            timers_before = _timer_seconds(data)
            steps_before = int(data.timer[step_timer].number)
        targets = DEFAULT_Q + rng.uniform(-ACTION_RANGE_RAD, ACTION_RANGE_RAD, (envs, 12))
        t0 = time.perf_counter()
        out, _ = rollout.rollout(
            model, data, state, targets[:, None, :], nstep=DECIMATION, skip_checks=False
        )
        elapsed = time.perf_counter() - t0
        state = out[:, -1, :]
        quat = state[:, quat_cols]
        up_z = 1.0 - 2.0 * (quat[:, 1] ** 2 + quat[:, 2] ** 2)
        fallen = (state[:, z_col] < 0.15) | (up_z < 0.5) | ~np.isfinite(state).all(axis=1)
        if fallen.any():
            state = state.copy()
            state[fallen] = start
        if step >= warmup:
            timed += elapsed
            physics_steps += envs * DECIMATION
            resets += int(fallen.sum())
    env_steps = envs * steps
    timers_after = _timer_seconds(data)
    timers = {name: timers_after[name] - timers_before[name] for name in TIMERS}
    return {
        "simulator": f"mujoco {mujoco.__version__}",
        "solver": solver,
        "cone": options.cone,
        "iterations": options.iterations,
        "ls_iterations": options.ls_iterations,
        "envs": envs,
        "threads": 1,
        "actions": "random",
        "env_steps_per_sec": round(env_steps / timed, 1),
        "physics_steps_per_sec": round(physics_steps / timed, 1),
        "env_steps_per_sec_per_thread": round(env_steps / timed, 1),
        "resets": resets,
        "timed_mj_steps": int(data.timer[step_timer].number) - steps_before,
        "us_per_robot_step": {
            k: round(v, 4) for k, v in stage_micros(timers, timed, physics_steps).items()
        },
    }


def server_bench(
    binary: Path,
    envs: int,
    steps: int,
    no_joints: bool = False,
    seed: int = 1,
    engine: str = "rapier",
) -> dict[str, Any]:
    """Run ``unigait-server bench`` on the reference loop, one thread, and return its record.

    Args:
        binary: The ``unigait-server`` executable.
        envs: Batch size.
        steps: Policy steps timed (after its 20 warm-up steps).
        no_joints: Build the robots without their joints (``--no-joints``).
        seed: Seed of the server's bench.
        engine: ``physics.engine`` (rapier's stages are the ones the tables break down).

    Returns:
        The bench's JSON record (``us_per_robot_step`` holds the engine's stages).
    """
    cmd = [str(binary), "bench", "--envs", str(envs), "--steps", str(steps), "--threads", "1"]
    cmd += ["--actions", "random", "--reference-loop", "--seed", str(seed)]
    cmd += ["--set", f"physics.engine = {json.dumps(engine)}", "--json"]
    if no_joints:
        cmd.append("--no-joints")
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    record: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    record["command"] = " ".join(["unigait-server", *cmd[1:-1]])
    return record


def compare(binary: Path, envs: int, steps: int) -> dict[str, dict[str, Any]]:
    """Both engines on the same loop, one after the other in this process's run.

    Returns:
        Records by column name: ``rapier`` and ``rapier_no_joints`` (the server's bench),
        ``playground`` and ``default`` (MuJoCo's solver settings).
    """
    return {
        "rapier": server_bench(binary, envs, steps),
        "rapier_no_joints": server_bench(binary, envs, steps, no_joints=True),
        "playground": run(envs, steps, "playground"),
        "default": run(envs, steps, "default"),
    }


RAPIER_ROWS: tuple[tuple[str, str], ...] = (
    ("physics_stage", "physics stage (env layer, all below)"),
    ("step", "our world step"),
    ("torques", "- ours: joint read-back, PD and stop torques"),
    ("pipeline", "- rapier's pipeline"),
    ("user_changes", "-- user changes"),
    ("collision_detection", "-- collision detection"),
    ("broad_phase", "--- broad phase"),
    ("narrow_phase", "--- narrow phase"),
    ("island_construction", "-- island construction"),
    ("constraints_collection", "-- constraint collection"),
    ("update", "-- body update and integration"),
    ("solver", "-- solver"),
    ("assembly", "--- constraint assembly"),
    ("resolution", "--- velocity resolution (substeps, PGS)"),
    ("ccd", "-- CCD"),
    ("rapier_other", "-- rest of the pipeline"),
    ("after", "- ours: contacts, extra-iteration flags"),
    ("read_back", "read-back (once a policy step)"),
)
"""Rapier's table: (key of the server's ``us_per_robot_step``, label); dashes give nesting."""

MUJOCO_ROWS: tuple[tuple[str, str], ...] = (
    ("step", "mj_step"),
    ("forward", "- forward"),
    ("position", "-- position"),
    ("pos_kinematics", "--- kinematics"),
    ("pos_inertia", "--- inertia (CRB, factorisation)"),
    ("pos_collision", "--- collision"),
    ("col_broadphase", "---- broad phase"),
    ("col_narrowphase", "---- narrow phase"),
    ("pos_make", "--- make constraints"),
    ("pos_project", "--- project constraints"),
    ("velocity", "-- velocity (bias forces, passive)"),
    ("actuation", "-- actuation"),
    ("constraint", "-- constraint solver"),
    ("forward_other", "-- rest (acceleration, sensors)"),
    ("advance", "- advance (implicitfast integration)"),
    ("step_other", "- rest (state checks)"),
    ("outside_step", "rollout outside mj_step"),
)
"""MuJoCo's table: (key of :func:`stage_micros`, label)."""


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def tables(records: dict[str, dict[str, Any]]) -> str:
    """Markdown: the summary, rapier's stages and MuJoCo's, in microseconds per robot step.

    Args:
        records: What :func:`compare` returned.
    """
    ours, free = records["rapier"], records["rapier_no_joints"]
    fast, default = records["playground"], records["default"]
    mj_total = fast["us_per_robot_step"]["wall"]

    def summary(name: str, r: dict[str, Any], physics_us: float, extra: str) -> list[str]:
        rate = r["env_steps_per_sec_per_thread"]
        return [name, f"{rate:,.0f}", f"{physics_us:.2f}", f"{mj_total / physics_us:.2f}x", extra]

    def contacts(r: dict[str, Any]) -> str:
        return (
            f"{r['contacts_per_robot_step']:.1f} contacts, "
            f"{r['constraints_per_robot_step']:.1f} constraints a robot step; "
            f"falls: {r['fall_resets']}"
        )

    head = [
        "engine, loop",
        "env steps/s per core",
        "us per robot physics step",
        "speed vs MuJoCo fast",
        "notes",
    ]
    rows = [
        summary(
            "rapier, Go2 (12 impulse joints)",
            ours,
            ours["us_per_robot_step"]["physics_stage"],
            contacts(ours) + f", joint gap {ours['max_joint_gap_m'] * 1000:.2f} mm",
        ),
        summary(
            "rapier, 13 free bodies a robot (no joints)",
            free,
            free["us_per_robot_step"]["physics_stage"],
            contacts(free),
        ),
        summary("MuJoCo, Playground's fast settings", fast, mj_total, f"falls: {fast['resets']}"),
        summary(
            "MuJoCo, default settings",
            default,
            default["us_per_robot_step"]["wall"],
            f"falls: {default['resets']}",
        ),
    ]
    out = ["Summary (ours: the env layer's physics stage; MuJoCo: the timed rollout calls):", ""]
    out += [_table(head, rows), ""]
    out += ["rapier (us per robot physics step):", ""]
    rap = [
        [label, f"{ours['us_per_robot_step'][k]:.2f}", f"{free['us_per_robot_step'][k]:.2f}"]
        for k, label in RAPIER_ROWS
    ]
    out += [_table(["stage", "Go2 (joints)", "no joints"], rap), ""]
    out += [f"MuJoCo {fast['simulator'].split()[-1]} (us per robot physics step):", ""]
    mj = [
        [
            label,
            f"{fast['us_per_robot_step'][k]:.2f}",
            f"{default['us_per_robot_step'][k]:.2f}",
        ]
        for k, label in MUJOCO_ROWS
    ]
    out += [_table(["timer", "Playground settings", "default settings"], mj)]
    return "\n".join(out)


def main(envs: int, steps: int, solvers: list[str], server: Path | None = None) -> int:
    """Print one JSON line per solver setting; with ``server``, both engines' tables as well."""
    if server is not None:
        records = compare(server, envs, steps)
        for record in records.values():
            print(json.dumps(record), flush=True)
        print(tables(records), flush=True)
        return 0
    for solver in solvers:
        print(json.dumps(run(envs, steps, solver)), flush=True)
    return 0
