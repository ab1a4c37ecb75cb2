"""MuJoCo's side of the simulation benchmark (``python -m unigait mujoco-bench``).

The bench steps MuJoCo with position actuators instead of Python PD torques, so the first test
checks that those actuators apply the server's PD law; the others check that both solver
settings run the bench loop and report what they ran.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from unigait.mujoco import bench  # noqa: E402
from unigait.mujoco.model import DEFAULT_Q, PhysicsOptions, build_model  # noqa: E402


def test_position_actuators_apply_the_servers_pd_law() -> None:
    go2 = build_model(dataclasses.replace(PhysicsOptions(), position_actuators=True))
    model = go2.model
    data = mujoco.MjData(model)
    data.qpos[2] = 0.5
    data.qpos[3] = 1.0
    q = DEFAULT_Q + np.linspace(-0.3, 0.3, 12)
    qd = np.linspace(2.0, -2.0, 12)
    data.qpos[go2.qpos_adr] = q
    data.qvel[go2.dof_adr] = qd
    # Targets 0.2 rad off, and one knee 3 rad off so that its torque saturates.
    targets = q + 0.2
    targets[2] = q[2] + 3.0
    data.ctrl[:] = targets
    mujoco.mj_forward(model, data)
    expected = np.clip(20.0 * (targets - q) - 0.5 * qd, -go2.effort, go2.effort)
    assert expected[2] == pytest.approx(go2.effort[2])
    np.testing.assert_allclose(data.actuator_force, expected, atol=1e-9)
    # In action order: actuator i drives joint i of the server's order.
    np.testing.assert_allclose(data.qfrc_actuator[go2.dof_adr], expected, atol=1e-9)


@pytest.mark.parametrize("solver", sorted(bench.SOLVERS))
def test_bench_runs_each_solver_setting(solver: str) -> None:
    record = bench.run(envs=8, steps=5, solver=solver, warmup=2)
    assert record["solver"] == solver
    assert record["envs"] == 8
    assert record["threads"] == 1
    assert record["env_steps_per_sec"] > 0.0
    assert record["physics_steps_per_sec"] == pytest.approx(
        record["env_steps_per_sec"] * bench.DECIMATION, rel=1e-3
    )
    expected = {"default": ("elliptic", 100, 50), "playground": ("pyramidal", 1, 5)}[solver]
    assert (record["cone"], record["iterations"], record["ls_iterations"]) == expected


def test_robots_stand_under_the_bench_loop() -> None:
    # Random targets of +-0.25 rad around the default pose do not make a standing Go2 fall
    # (both engines' robots stay up, so the bench times upright, moving robots): few resets.
    record = bench.run(envs=16, steps=40, solver="default", warmup=0)
    assert record["resets"] <= 2
