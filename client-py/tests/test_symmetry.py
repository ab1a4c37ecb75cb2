"""The left-right mirror maps and the mirror loss (decision record 0033)."""

from __future__ import annotations

import csv

import pytest
import torch
from fakes import SMALL, FakeSession, proto_spec

from unigait.algorithms import PPO, PPOConfig
from unigait.algorithms.symmetry import (
    ActorMirror,
    UnknownField,
    joint_mirror,
    mirror_loss,
    tensor_mirror,
)
from unigait.client import Spec
from unigait.client.proto import pb
from unigait.config import load_config
from unigait.env import TorchVecEnv
from unigait.modules import ActorCritic
from unigait.runners import OnPolicyRunner
from unigait.storage import RolloutStorage

HISTORY = 3


def spec() -> Spec:
    return Spec.from_proto(proto_spec(4))


def test_the_joint_mirror_swaps_legs_and_flips_the_hips() -> None:
    legs, joints = ("FL", "FR", "RL", "RR"), ("hip", "thigh", "calf")
    names = tuple(f"{leg}_{j}_joint" for leg in legs for j in joints)
    q = torch.tensor([0.3, 0.9, -1.4, -0.2, 0.7, -1.6, 0.05, 1.1, -1.3, 0.0, 1.2, -1.7])
    mirrored = joint_mirror(names)(q)
    expected = [0.2, 0.7, -1.6, -0.3, 0.9, -1.4, 0.0, 1.2, -1.7, -0.05, 1.1, -1.3]
    assert mirrored.tolist() == pytest.approx(expected)


def test_the_observation_mirror_on_known_values() -> None:
    s = spec()
    m = tensor_mirror(s, "obs")
    o = torch.zeros(53)
    o[s.obs.slice("cmd")] = torch.tensor([1.0, 0.4, 0.1])
    o[s.obs.slice("phi")] = torch.tensor([0.2, 1.3, -0.5])
    o[s.obs.slice("omega")] = torch.tensor([0.3, -0.6, 0.9])
    o[s.obs.slice("q")] = torch.arange(12.0)
    o[s.obs.slice("mode")] = torch.tensor([1.0, 0.0])
    o[s.obs.slice("clock")] = torch.tensor([0.5, -0.5, 0.0, 0.0])
    o[s.obs.slice("ratio")] = torch.tensor([0.4, 0.6])
    r = m(o)
    assert r[s.obs.slice("cmd")].tolist() == pytest.approx([1.0, -0.4, -0.1])
    # gravity y flips (the roll measure), pitch and gravity z do not
    assert r[s.obs.slice("phi")].tolist() == pytest.approx([-0.2, 1.3, -0.5])
    # angular velocity is a pseudovector: roll and yaw rates flip, the pitch rate does not
    assert r[s.obs.slice("omega")].tolist() == pytest.approx([-0.3, -0.6, -0.9])
    q = [-3.0, 4.0, 5.0, -0.0, 1.0, 2.0, -9.0, 10.0, 11.0, -6.0, 7.0, 8.0]
    assert r[s.obs.slice("q")].tolist() == pytest.approx(q)
    assert r[s.obs.slice("mode")].tolist() == [1.0, 0.0]
    assert r[s.obs.slice("clock")].tolist() == pytest.approx([-0.5, 0.5, 0.0, 0.0])
    assert r[s.obs.slice("ratio")].tolist() == pytest.approx([0.4, 0.6])


def test_the_label_mirror_on_known_values() -> None:
    s = spec()
    e = torch.tensor([0.5, 0.2, -0.1, 1, 0, 0, 1, 0.1, 0.3, 0.9, 0.02, 0.08, 0.0, 0.05])
    r = tensor_mirror(s, "labels")(e)
    expected = [0.5, -0.2, -0.1, 0, 1, 1, 0, 0.1, -0.3, 0.9, 0.08, 0.02, 0.05, 0.0]
    assert r.tolist() == pytest.approx(expected)


def test_mirroring_twice_gives_back_the_input() -> None:
    m = ActorMirror.from_spec(spec(), HISTORY)
    x = torch.randn(7, 53 * HISTORY + 14)
    a = torch.randn(7, 12)
    assert torch.equal(m.actor_obs(m.actor_obs(x)), x)
    assert torch.equal(m.actions(m.actions(a)), a)
    # the history's three copies of o_t mirror alike, the estimate after them
    assert torch.equal(m.actor_obs(x)[:, 53:106], tensor_mirror(spec(), "obs")(x[:, 53:106]))


def test_a_field_without_a_mirror_is_refused() -> None:
    msg = proto_spec(4)
    obs = next(t for t in msg.tensors if t.name == "obs")
    obs.fields.add(name="height_scan", offset=53, size=5)
    obs.shape[0] = 58
    with pytest.raises(UnknownField, match="height_scan"):
        ActorMirror.from_spec(Spec.from_proto(msg), HISTORY)
    assert pb.Spec  # the fake spec is the real message type


def test_the_mirror_loss_on_known_numbers() -> None:
    m = ActorMirror.from_spec(spec(), HISTORY)
    mean = torch.zeros(1, 12)
    mean[0, 0] = 0.5  # FL hip: its mirror is -0.5 on the FR hip
    mirrored = torch.zeros(1, 12, requires_grad=True)
    loss = mirror_loss(mean, mirrored, m)
    assert loss.item() == pytest.approx(0.25 / 12)
    loss.backward()
    assert mirrored.grad is not None
    assert mirrored.grad[0, 3].item() == pytest.approx(2 * 0.5 / 12)


def test_an_equivariant_actor_pays_no_mirror_loss() -> None:
    m = ActorMirror.from_spec(spec(), HISTORY)
    torch.manual_seed(0)
    f = torch.nn.Linear(53 * HISTORY + 14, 12)

    def symmetric(x: torch.Tensor) -> torch.Tensor:
        return 0.5 * (f(x) + m.actions(f(m.actor_obs(x))))

    x = torch.randn(64, 53 * HISTORY + 14)
    assert mirror_loss(symmetric(x), symmetric(m.actor_obs(x)), m).item() < 1e-12
    assert mirror_loss(f(x), f(m.actor_obs(x)), m).item() > 0.01


def filled_storage(
    actor_in: int, critic_in: int, steps: int = 8, envs: int = 512
) -> RolloutStorage:
    """A rollout whose rewards and values are all zero: the advantages are zero, and PPO's
    surrogate has nothing to say."""
    torch.manual_seed(1)
    history = actor_in - 14
    st = RolloutStorage(steps, envs, actor_in, history, critic_in, 14, 12, torch.device("cpu"))
    for _ in range(steps):
        st.add(
            torch.randn(envs, actor_in),
            torch.randn(envs, critic_in),
            torch.zeros(envs, 14),
            torch.zeros(envs, 12),
            torch.zeros(envs),
            torch.zeros(envs, 12),
            torch.ones(envs, 12),
            torch.zeros(envs),
            torch.zeros(envs),
            torch.zeros(envs, dtype=torch.bool),
        )
    st.compute_returns(torch.zeros(envs), 0.99, 0.95)
    return st


def test_the_mirror_loss_alone_makes_the_actor_symmetric() -> None:
    actor_in, critic_in = 53 * HISTORY + 14, 64
    m = ActorMirror.from_spec(spec(), HISTORY)
    torch.manual_seed(2)
    ac = ActorCritic(actor_in, critic_in, 12, [32], [32], "elu", 1.0)
    st = filled_storage(actor_in, critic_in)
    x = torch.randn(256, actor_in)

    def asymmetry() -> float:
        with torch.no_grad():
            return mirror_loss(ac.act_inference(x), ac.act_inference(m.actor_obs(x)), m).item()

    before = asymmetry()
    cfg = PPOConfig(entropy_coef=0.0, schedule="fixed", learning_rate=1e-3, mirror_loss_coef=1.0)
    ppo = PPO(ac, cfg, m)
    stats = {}
    for _ in range(10):
        stats = ppo.update(st)
    assert "mirror_loss" in stats
    assert asymmetry() < 0.1 * before
    with pytest.raises(ValueError, match="mirror"):
        PPO(ac, cfg)
    # without a weight, no mirror term and no figure
    assert "mirror_loss" not in PPO(ac, PPOConfig(), m).update(st)


def test_a_run_with_the_mirror_loss_logs_it_and_checkpoints(tmp_path) -> None:
    """The runner builds the maps from the session's spec and logs the figure per iteration."""
    torch.manual_seed(0)
    cfg = load_config(None, [*SMALL, "ppo.mirror_loss_coef=0.2"])
    runner = OnPolicyRunner(TorchVecEnv(FakeSession(8)), cfg, tmp_path)
    history = runner.learn(2)
    assert all(h["mirror_loss"] > 0.0 for h in history)
    with (tmp_path / "progress.csv").open() as f:
        assert "mirror_loss" in next(csv.DictReader(f))
    plain = OnPolicyRunner(TorchVecEnv(FakeSession(8)), load_config(None, SMALL), None)
    assert "mirror_loss" not in plain.learn(1)[0]
