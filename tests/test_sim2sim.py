"""sim2sim: the observation MuJoCo rollouts feed a policy equals the server's, slice by slice.

The server's side comes from the cross-check driver (``target/release/unigait-crosscheck
observations task``): states of a calm ``VecEnv`` (Table IV initial states, random
initial episode steps, pseudo-random actions, no randomisation, no noise) with the o_t the env
wrote for each. Each state is loaded into the MuJoCo env sim2sim runs and observed there; every
slice must agree to 1e-5. The shipped test policy then runs through ``python -m unigait sim2sim``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mujoco", reason="the MuJoCo tests need the `mujoco` extra")
pytest.importorskip("onnxruntime", reason="sim2sim needs onnxruntime (the `mujoco` extra)")

from unigait.cli import main
from unigait.mujoco import cli as mujoco_cli
from unigait.mujoco import sim2sim
from unigait.mujoco.crosscheck import run_ours
from unigait.mujoco.model import DEFAULT_Q, build_model
from unigait.mujoco.observation import (
    OBS_DIM,
    OBSERVATION,
    QUAD,
    TaskSettings,
    obs_slice,
)
from unigait.mujoco.vec_env import MujocoVecEnv

DATA = Path(__file__).resolve().parent / "data"
TEST_POLICY = DATA / "test_policy.onnx"
OBS_TOLERANCE = 1e-5


@pytest.fixture(scope="module")
def server_side(crosscheck_bin: Path) -> dict:
    return run_ours(crosscheck_bin, ["observations", "task", "robot"])


def test_the_observation_table_is_the_servers(server_side):
    table = server_side["task"]["observation"]
    assert [f["name"] for f in table] == [f.name for f in OBSERVATION]
    assert [int(f["dim"]) for f in table] == [f.dim for f in OBSERVATION]
    for ours, theirs in zip(OBSERVATION, table, strict=True):
        np.testing.assert_allclose(ours.scale, theirs["scale"], rtol=0, atol=1e-7)
    assert OBS_DIM == 53


def test_the_task_settings_are_the_servers(server_side):
    t, s = server_side["task"], TaskSettings()
    assert s.policy_dt == pytest.approx(t["policy_dt"], abs=1e-7)
    assert s.decimation == t["decimation"]
    assert s.action_scale == pytest.approx(t["action_scale"])
    assert s.clip_actions == pytest.approx(t["clip_actions"])
    assert s.clip_observations == pytest.approx(t["clip_observations"])
    assert s.gait_period_s == pytest.approx(t["gait_period_s"], abs=1e-7)
    assert s.swing_ratio == pytest.approx(t["swing_ratio"], abs=1e-7)
    assert list(s.offsets_quad) == pytest.approx(t["offsets_quad"])
    assert list(s.offsets_biped) == pytest.approx(t["offsets_biped"])
    assert s.upright_pitch == pytest.approx(t["upright_pitch"], abs=1e-7)
    assert s.episode_length_s == pytest.approx(t["episode_length_s"])
    np.testing.assert_allclose(DEFAULT_Q, server_side["robot"]["default_q"], atol=1e-7)


def test_observation_equals_the_servers_slice_by_slice(server_side):
    samples = server_side["observations"]["samples"]
    assert len(samples) >= 24
    modes = {int(s["mode"]) for s in samples}
    assert modes == {1, 2}, "the dump should hold both modes"
    settings = TaskSettings()
    ranges = {1: settings.biped_ranges, 2: settings.quad_ranges}
    env = MujocoVecEnv(build_model(), 1, settings, QUAD, ranges)
    worst: dict[str, float] = {}
    for s in samples:
        x, y, z, w = s["base_quat_xyzw"]
        state = {
            "base_pos": np.array(s["base_pos"]),
            "base_quat": np.array([w, x, y, z]),
            "base_linvel": np.array(s["base_linvel"]),
            "base_angvel": np.array(s["base_angvel"]),
            "q": np.array(s["q"]),
            "qd": np.array(s["qd"]),
        }
        obs = env.load(
            0,
            state,
            int(s["mode"]),
            np.array(s["command"]),
            int(s["episode_step"]),
            np.array(s["last_action"]),
        )
        expected = np.array(s["obs"], dtype=np.float32)
        for f in OBSERVATION:
            sl = obs_slice(f.name)
            err = float(np.max(np.abs(obs[sl] - expected[sl])))
            worst[f.name] = max(worst.get(f.name, 0.0), err)
            assert err <= OBS_TOLERANCE, (
                f"env {s['env']} step {s['step']} slice {f.name}: "
                f"MuJoCo {obs[sl]} vs server {expected[sl]}"
            )
    print("worst difference per slice:", worst)


def test_the_policy_reads_the_history_as_exported():
    policy = sim2sim.OnnxPolicy(TEST_POLICY)
    b = np.arange(4)[:, None]
    k = np.arange(3 * 53)[None, :]
    x = (((b * 53 + k * 17) % 101).astype(np.float32) / np.float32(50.0) - np.float32(1.0)).reshape(
        4, 3, 53
    )
    expected = np.fromfile(DATA / "test_policy_expected.f32", dtype="<f4").reshape(-1, 12)[:4]
    np.testing.assert_allclose(policy(x), expected, atol=1e-5)


def test_the_cli_lists_every_scenario():
    assert set(mujoco_cli.SIM2SIM_SCENARIOS) == set(sim2sim.SCENARIOS)


def test_sim2sim_runs_the_test_policy(tmp_path, capsys):
    report = tmp_path / "report.json"
    code = main(
        [
            "sim2sim",
            "--policy",
            str(TEST_POLICY),
            "--scenario",
            "transition_quad_to_biped",
            "--num-envs",
            "2",
            "--report",
            str(report),
        ]
    )
    assert code == 0
    metrics = json.loads(report.read_text())["metrics"]
    # Two envs start in quad mode, level: both are in the quad posture at the switch unless they
    # fell, and every quad step from 1 s on is a tracking sample until the switch.
    assert metrics["switched_envs"] == 2
    assert metrics["trials"] + metrics["fell_before_switch"] == 2
    assert metrics["tracking/quad/samples"] > 0
    assert all(math.isfinite(v) for v in metrics.values())
    assert "tracking/quad/lin_vel_error_mps" in capsys.readouterr().out
