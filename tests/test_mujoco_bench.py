"""MuJoCo's side of the simulation benchmark (``python -m unigait mujoco-bench``).

The bench steps MuJoCo with position actuators instead of Python PD torques, so the first test
checks that those actuators apply the server's PD law; the others check that both solver
settings run the bench loop and report what they ran.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

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


def test_stage_micros_divides_by_robot_steps_and_derives_the_remainders() -> None:
    timers = dict.fromkeys(bench.TIMERS, 0.0)
    timers.update(step=0.010, forward=0.008, position=0.004, velocity=0.001, actuation=0.0005)
    timers.update(constraint=0.002, advance=0.0015)
    us = bench.stage_micros(timers, wall_s=0.012, robot_steps=1000)
    # 10 ms over 1000 robot steps: 10 us each.
    assert us["step"] == pytest.approx(10.0)
    assert us["forward_other"] == pytest.approx(8.0 - 4.0 - 1.0 - 0.5 - 2.0)
    assert us["step_other"] == pytest.approx(10.0 - 8.0 - 1.5)
    assert us["wall"] == pytest.approx(12.0)
    assert us["outside_step"] == pytest.approx(2.0)


def test_bench_times_every_robot_step_in_mujocos_timers() -> None:
    record = bench.run(envs=6, steps=3, solver="playground", warmup=2)
    # rollout steps all 6 robots through one MjData: its step timer counts them all, and the
    # warm-up's are left out.
    assert record["timed_mj_steps"] == 6 * 3 * bench.DECIMATION
    us = record["us_per_robot_step"]
    assert us["wall"] >= us["step"] >= us["forward"] >= us["position"] > 0.0
    assert us["position"] >= us["pos_collision"] >= us["col_broadphase"]
    assert us["constraint"] > 0.0


def _server_record(physics_us: float, contacts: float, **extra: float) -> dict[str, object]:
    stages = dict.fromkeys((k for k, _ in bench.RAPIER_ROWS), 1.0)
    stages["physics_stage"] = physics_us
    return {
        "env_steps_per_sec_per_thread": 1e6 / (4 * physics_us),
        "contacts_per_robot_step": contacts,
        "constraints_per_robot_step": contacts + 12,
        "fall_resets": 0,
        "max_joint_gap_m": 0.002,
        "us_per_robot_step": stages,
        **extra,
    }


def _mujoco_record(wall_us: float) -> dict[str, object]:
    stages = dict.fromkeys((k for k, _ in bench.MUJOCO_ROWS), 0.5)
    stages["wall"] = wall_us
    return {
        "simulator": "mujoco 4.0.0",
        "env_steps_per_sec_per_thread": 1e6 / (4 * wall_us),
        "resets": 3,
        "us_per_robot_step": stages,
    }


def test_tables_put_both_engines_side_by_side() -> None:
    records = {
        "rapier": _server_record(32.0, 8.0),
        "rapier_no_joints": _server_record(16.0, 20.0),
        "playground": _mujoco_record(16.0),
        "default": _mujoco_record(64.0),
    }
    text = bench.tables(records)
    lines = text.splitlines()
    # Speed against MuJoCo's fast settings: 16 us / 32 us, 16 / 16, 16 / 64.
    assert "| rapier, Go2 (12 impulse joints) | 7,812 | 32.00 | 0.50x |" in text
    assert "| MuJoCo, Playground's fast settings | 15,625 | 16.00 | 1.00x |" in text
    assert "| MuJoCo, default settings | 3,906 | 64.00 | 0.25x |" in text
    assert any(line.startswith("| -- solver | 1.00 | 1.00 |") for line in lines)
    assert any(line.startswith("| -- constraint solver | 0.50 | 0.50 |") for line in lines)
    assert "MuJoCo 4.0.0" in text


def test_server_bench_reports_rapiers_stages(server_bin: Path) -> None:
    jointed = bench.server_bench(server_bin, envs=4, steps=2)
    free = bench.server_bench(server_bin, envs=4, steps=2, no_joints=True)
    assert not jointed["no_joints"] and free["no_joints"]
    assert jointed["reference_loop"] and jointed["threads"] == 1
    # The 12 joints are constraints of the jointed robots only: without them every constraint
    # is a contact manifold of at least one point.
    assert jointed["constraints_per_robot_step"] >= 12.0
    assert free["constraints_per_robot_step"] <= free["contacts_per_robot_step"]
    for record in (jointed, free):
        assert record["us_per_robot_step"]["pipeline"] > 0.0
