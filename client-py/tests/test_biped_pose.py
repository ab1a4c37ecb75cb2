"""Biped pose statistics per rollout, and a resumed run's CSV gaining their columns."""

import csv
import math

import torch
from fakes import SMALL, FakeSession, proto_spec

from unigait.client import Spec
from unigait.config import load_config
from unigait.env import BipedPoseStats, TorchStep, TorchVecEnv
from unigait.runners import OnPolicyRunner


def _step(
    spec: Spec,
    pitch: list[float],
    rear_contact: list[bool],
    head: list[bool] | None,
    done: list[bool] | None = None,
) -> TorchStep:
    n = len(pitch)
    obs = torch.zeros(n, spec.obs_dim)
    obs[:, spec.pitch_index] = torch.tensor(pitch)
    labels = torch.zeros(n, spec.label_dim)
    contact = spec.labels.field("foot_contact").offset
    labels[:, contact : contact + 2] = 1.0  # front feet down everywhere
    labels[:, contact + 2 : contact + 4] = torch.tensor(rear_contact, dtype=torch.float32)[:, None]
    empty = torch.zeros(0)
    return TorchStep(
        obs=obs,
        labels=labels,
        privileged=torch.zeros(n, spec.privileged_dim),
        reward=torch.zeros(n),
        reward_terms=None,
        terminated=torch.zeros(n, dtype=torch.bool),
        truncated=torch.tensor(done or [False] * n),
        final_env_ids=empty.long(),
        final_obs=empty,
        final_labels=empty,
        final_privileged=empty,
        final_episode_length=empty.long(),
        mode=torch.full((n,), 2),
        terrain_level=torch.zeros(n, dtype=torch.int64),
        head_contact=None if head is None else torch.tensor(head),
    )


def test_biped_pose_counts_only_biped_env_steps():
    spec = Spec.from_proto(proto_spec(4))
    assert spec.upright_pitch == 1.4
    stats = BipedPoseStats(spec, upright_pitch=1.4, device=torch.device("cpu"))
    # The server's layout (observation.rs): pitch is o_t[4], the rear feet's contacts e_t[5:7].
    assert stats.pitch_index == 4 and stats.rear_feet == slice(5, 7)
    # Envs 0-2 acted in biped mode, env 3 in quad mode (upright, head down: must not count).
    mode = torch.tensor([1, 1, 1, 2])
    # Env 0 upright on its front feet; env 1 on its head with the rear feet tucked up (the
    # stepping stone); env 2 low with its rear feet down.
    after = _step(
        spec, [1.5, 0.3, 0.3, 1.5], [False, False, True, False], [False, True, False, True]
    )
    stats.add(mode, after)
    stats.add(mode, after)
    s = stats.summary()
    assert math.isclose(s["biped_pose/pitch"], (1.5 + 0.3 + 0.3) / 3, rel_tol=1e-6)
    assert math.isclose(s["biped_pose/upright_share"], 1 / 3, rel_tol=1e-6)
    assert math.isclose(s["biped_pose/head_contact_share"], 1 / 3, rel_tol=1e-6)
    assert math.isclose(s["biped_pose/rear_feet_up_share"], 2 / 3, rel_tol=1e-6)
    # Cleared: a rollout without biped steps reports NaN, not the last rollout's figures.
    stats.add(torch.full((4,), 2), after)
    assert all(math.isnan(v) for v in stats.summary().values())


def test_a_resumed_run_widens_its_progress_csv_for_new_columns(tmp_path):
    cfg = load_config(None, SMALL)
    OnPolicyRunner(TorchVecEnv(FakeSession(8)), cfg, tmp_path).learn(1)
    path = tmp_path / "progress.csv"
    with path.open() as f:
        rows = list(csv.reader(f))
    # Written before the biped pose (and, to see a value land, the throughput) was logged.
    dropped = ("biped_pose/", "env_steps_per_s")
    keep = [i for i, c in enumerate(rows[0]) if not c.startswith(dropped)]
    assert len(keep) == len(rows[0]) - 5
    with path.open("w", newline="") as f:
        csv.writer(f).writerows([[r[i] for i in keep] for r in rows])

    OnPolicyRunner(TorchVecEnv(FakeSession(8)), cfg, tmp_path).learn(1)
    with path.open() as f:
        new_rows = list(csv.DictReader(f))
    assert len(new_rows) == 2
    old, new = new_rows
    assert old["iteration"] == new["iteration"] == "1"  # the same iteration, logged twice
    assert old["env_steps_per_s"] == "" and float(new["env_steps_per_s"]) > 0
    assert old["mean_step_reward"] == rows[1][rows[0].index("mean_step_reward")]
    assert new["biped_pose/head_contact_share"] == ""  # NaN: the fakes run quad mode only


def test_biped_pose_leaves_out_ended_episodes_and_unreported_heads():
    spec = Spec.from_proto(proto_spec(3))
    stats = BipedPoseStats(spec, upright_pitch=1.4, device=torch.device("cpu"))
    biped = torch.tensor([1, 1, 1])
    # Env 2's episode ended: its obs is the next episode's spawn (pitch 1.2, contacts cleared),
    # which must not count. The server reports no head contact here.
    stats.add(biped, _step(spec, [0.2, 1.5, 1.2], [True, False, False], None, [False, False, True]))
    s = stats.summary()
    assert math.isclose(s["biped_pose/pitch"], (0.2 + 1.5) / 2, rel_tol=1e-6)
    assert math.isclose(s["biped_pose/upright_share"], 0.5, rel_tol=1e-6)
    assert math.isclose(s["biped_pose/rear_feet_up_share"], 0.5, rel_tol=1e-6)
    assert math.isnan(s["biped_pose/head_contact_share"])  # unknown, not "never"
