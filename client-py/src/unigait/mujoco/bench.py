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
degrees (the server's bench resets on the task's terminations instead; both keep the batch of
mostly upright, moving robots that training sees).
"""

from __future__ import annotations

import dataclasses
import json
import time
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
    for step in range(warmup + steps):
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
    }


def main(envs: int, steps: int, solvers: list[str]) -> int:
    """Print one JSON line per solver setting."""
    for solver in solvers:
        print(json.dumps(run(envs, steps, solver)), flush=True)
    return 0
