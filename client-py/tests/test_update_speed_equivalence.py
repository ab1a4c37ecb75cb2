"""The faster update keeps the algorithm: ELU, mini-batch partitions, losses and step counts.

The update's speed-ups (ELU from ``exp``, one packed rollout tensor shuffled once per epoch into a
kept buffer) must leave the learner as the paper has it: the same function, the same samples in
the same mini-batches for a seed, the same losses and the same number of gradient steps.
"""

import math

import pytest
import torch
from torch import nn
from torch.nn import functional

from unigait.algorithms import PPO, EstimatorConfig, EstimatorLearning, PPOConfig
from unigait.modules import ActorCritic, Estimator, EstimatorActorPolicy, mlp
from unigait.modules.mlp import ELU
from unigait.storage import RolloutStorage

# Storage of T=3 steps x N=4 envs, actor input 5 (history 3 + estimate 2), critic 2, labels 2,
# 1 action: small enough to check every sample.
T, N = 3, 4


def coded_storage() -> RolloutStorage:
    """Every value of sample k = t * N + n is ``1000 k + 10 field + column``: rows identify."""
    st = RolloutStorage(T, N, 5, 3, 2, 2, 1)

    def field(f: int, width: int, t: int) -> torch.Tensor:
        ids = torch.arange(N, dtype=torch.float32) + t * N
        return 1000 * ids[:, None] + 10 * f + torch.arange(width, dtype=torch.float32)

    for t in range(T):
        st.add(
            field(0, 5, t),
            field(1, 2, t),
            field(2, 2, t),
            field(3, 1, t),
            field(4, 1, t)[:, 0],
            field(5, 1, t),
            field(6, 1, t),
            field(7, 1, t)[:, 0],
            torch.zeros(N),
            torch.zeros(N),
        )
    # Fields 8 and 9 (1000 k + 80, + 90): filled by compute_returns in a run.
    st.advantages.copy_(st.actions[..., 0] + 50)
    st.returns.copy_(st.actions[..., 0] + 60)
    return st


def sample_ids(rows: torch.Tensor) -> list[int]:
    """The sample ids of rows whose first column is ``1000 k``."""
    return [int(v) // 1000 for v in rows[:, 0].tolist()]


def expected(ids: list[int], f: int, width: int) -> torch.Tensor:
    k = torch.tensor(ids, dtype=torch.float32)
    return 1000 * k[:, None] + 10 * f + torch.arange(width, dtype=torch.float32)


def test_storage_fields_read_back_what_was_added():
    st = coded_storage()
    # Sample t=2, n=1 is id 9.
    assert st.actor_obs[2, 1].tolist() == [9000.0, 9001.0, 9002.0, 9003.0, 9004.0]
    assert st.critic_obs[2, 1].tolist() == [9010.0, 9011.0]
    assert st.labels[2, 1].tolist() == [9020.0, 9021.0]
    assert st.log_prob[2, 1].item() == 9040.0
    assert st.values[2, 1].item() == 9070.0
    assert st.advantages[2, 1].item() == 9080.0
    assert st.returns[2, 1].item() == 9090.0


@pytest.mark.parametrize(("num_mini_batches", "size"), [(4, 3), (5, 2), (1, 12)])
def test_mini_batches_partition_each_epoch_as_the_permutation_says(num_mini_batches, size):
    st = coded_storage()
    n, epochs = T * N, 3
    torch.manual_seed(7)
    perms = [torch.randperm(n).tolist() for _ in range(epochs)]
    torch.manual_seed(7)
    batches = st.mini_batches(num_mini_batches, epochs)
    for perm in perms:
        seen: list[int] = []
        for i in range(num_mini_batches):
            mb = next(batches)
            ids = sample_ids(mb.actor_obs)
            # Mini-batch i is perm[i*B:(i+1)*B], as the per-mini-batch gathers took it.
            assert ids == perm[i * size : (i + 1) * size]
            # Every field of a row belongs to that row's sample.
            torch.testing.assert_close(mb.actor_obs, expected(ids, 0, 5))
            torch.testing.assert_close(mb.critic_obs, expected(ids, 1, 2))
            torch.testing.assert_close(mb.actions, expected(ids, 3, 1))
            torch.testing.assert_close(mb.old_log_prob, expected(ids, 4, 1)[:, 0])
            torch.testing.assert_close(mb.old_mu, expected(ids, 5, 1))
            torch.testing.assert_close(mb.old_sigma, expected(ids, 6, 1))
            torch.testing.assert_close(mb.old_values, expected(ids, 7, 1)[:, 0])
            torch.testing.assert_close(mb.advantages, expected(ids, 8, 1)[:, 0])
            torch.testing.assert_close(mb.returns, expected(ids, 9, 1)[:, 0])
            seen += ids
        # Each sample at most once per epoch; all of them when B divides T * N.
        assert len(seen) == len(set(seen)) == num_mini_batches * size
    assert next(batches, None) is None


@pytest.mark.parametrize(("batch_size", "per_epoch"), [(4, 3), (5, 2), (12, 1), (50, 1)])
def test_estimator_batches_partition_each_epoch(batch_size, per_epoch):
    st = coded_storage()
    n, epochs = T * N, 2
    torch.manual_seed(3)
    perms = [torch.randperm(n).tolist() for _ in range(epochs)]
    torch.manual_seed(3)
    batches = st.estimator_batches(batch_size, epochs)
    for perm in perms:
        seen: list[int] = []
        for k in range(per_epoch):
            history, labels = next(batches)
            ids = sample_ids(history)
            assert ids == perm[k * batch_size : (k + 1) * batch_size]
            # The history is the actor input's first 3 columns (not the estimate); labels e_t.
            torch.testing.assert_close(history, expected(ids, 0, 3))
            torch.testing.assert_close(labels, expected(ids, 2, 2))
            seen += ids
        assert len(seen) == len(set(seen)) == min(n, per_epoch * batch_size)
    assert next(batches, None) is None


def test_elu_matches_torch_to_a_float_step_and_its_gradient_exactly():
    assert ELU()(torch.tensor([-1.0, 0.0, 2.0])).tolist() == pytest.approx(
        [math.exp(-1.0) - 1.0, 0.0, 2.0], abs=6e-8
    )
    x = torch.cat([torch.linspace(-30.0, 10.0, 100_001), torch.tensor([-1e-6, -1e-30, 0.0])])
    # exp(x) - 1 against expm1(x): within one float32 step of 1.0.
    assert (ELU()(x) - functional.elu(x)).abs().max().item() <= 2**-24
    xs = (3 * torch.randn(64, 32, generator=torch.Generator().manual_seed(0))).requires_grad_()
    grad_out = torch.randn(64, 32, generator=torch.Generator().manual_seed(1))
    (ours,) = torch.autograd.grad(ELU()(xs), xs, grad_out)
    (theirs,) = torch.autograd.grad(functional.elu(xs), xs, grad_out)
    assert torch.equal(ours, theirs)


@pytest.mark.filterwarnings("ignore:`torch.jit.trace")
def test_traced_policy_keeps_torch_elu():
    # The ONNX export traces the policy: its graph must hold aten::elu (ONNX Elu), not a Python op.
    policy = EstimatorActorPolicy(Estimator(6, 2, (8,)), mlp(8, (8,), 3)).eval()
    traced = torch.jit.trace(policy, torch.randn(2, 3, 2))
    kinds = {node.kind() for node in traced.inlined_graph.nodes()}
    assert "aten::elu" in kinds and "prim::PythonOp" not in kinds


def zeroed(module: nn.Module) -> None:
    with torch.no_grad():
        for p in module.parameters():
            p.zero_()


def test_estimator_step_is_mse_on_a_hand_made_batch():
    est = Estimator(3, 2, (4,))
    zeroed(est)  # output 0 for every input
    st = RolloutStorage(1, 2, 5, 3, 2, 2, 1)
    labels = torch.tensor([[1.0, 2.0], [3.0, -1.0]])
    st.add(
        torch.randn(2, 5),
        torch.zeros(2, 2),
        labels,
        torch.zeros(2, 1),
        torch.zeros(2),
        torch.zeros(2, 1),
        torch.ones(2, 1),
        torch.zeros(2),
        torch.zeros(2),
        torch.zeros(2),
    )
    cfg = EstimatorConfig(learning_rate=0.1, mini_batch_size=768, num_epochs=1)
    learning = EstimatorLearning(est, cfg)
    stats = learning.update(st)
    # MSE of 0 against the labels: (1 + 4 + 9 + 1) / 4.
    assert stats["estimator_loss"] == pytest.approx(3.75)
    # Only the output bias has a gradient (the hidden layer is ELU(0) = 0 and the output weights
    # 0): d/db_j = 2/4 * sum_b (0 - y_bj) = [-2, -0.5]; Adam's first step is lr * g / (|g| + eps).
    assert est.net[-1].bias.tolist() == pytest.approx([0.1, 0.1], abs=1e-6)
    assert est.net[0].weight.abs().max().item() == 0.0


def test_ppo_losses_on_a_four_sample_hand_computed_case():
    ac = ActorCritic(3, 2, 1, (4,), (4,), init_noise_std=1.0)
    zeroed(ac)  # mean action 0, value 0, std exp(0) = 1
    st = RolloutStorage(1, 4, 3, 2, 2, 1, 1)
    actions = torch.tensor([0.5, -1.0, 2.0, 0.0])
    log_prob = -0.5 * actions.square() - 0.5 * math.log(2 * math.pi)
    ratios = torch.tensor([1.5, 0.5, 1.0, 1.1])
    st.add(
        torch.randn(4, 3),
        torch.randn(4, 2),
        torch.zeros(4, 1),
        actions[:, None],
        log_prob - ratios.log(),  # so that exp(log_prob - old) is the ratio
        torch.tensor([[0.0], [0.2], [0.0], [0.0]]),
        torch.tensor([[1.0], [1.0], [2.0], [1.0]]),
        torch.tensor([0.5, -0.1, 0.0, 1.0]),
        torch.zeros(4),
        torch.zeros(4),
    )
    st.advantages.copy_(torch.tensor([[1.0, -1.0, 2.0, -2.0]]))
    st.returns.copy_(torch.tensor([[1.0, 1.0, -1.0, 0.3]]))
    cfg = PPOConfig(num_learning_epochs=1, num_mini_batches=1, learning_rate=1e-3)
    stats = PPO(ac, cfg).update(st)
    # max(-A r, -A clip(r, 0.8, 1.2)): -1.2, 0.8, -2, 2.2.
    assert stats["surrogate_loss"] == pytest.approx((-1.2 + 0.8 - 2.0 + 2.2) / 4)
    # V = 0; clipped V = old + clip(0 - old, +-0.2) = 0.3, 0, 0, 0.8; max of squared errors:
    # max(1, 0.49), max(1, 1), max(1, 1), max(0.09, 0.25).
    assert stats["value_loss"] == pytest.approx((1.0 + 1.0 + 1.0 + 0.25) / 4)
    assert stats["entropy"] == pytest.approx(0.5 * math.log(2 * math.pi * math.e))
    # KL(old || N(0, 1)) = ln(1/s_old + 1e-5) + (s_old^2 + mu_old^2) / 2 - 0.5.
    kls = [math.log(1 / s + 1e-5) + (s * s + m * m) / 2 - 0.5 for m, s in ((0, 1), (0.2, 1))]
    kls += [math.log(0.5 + 1e-5) + 4 / 2 - 0.5, kls[0]]
    assert stats["kl"] == pytest.approx(sum(kls) / 4, rel=1e-5)
    # That KL (0.207) is above 2 x 0.01: the adaptive rule shrinks the rate once.
    assert stats["learning_rate"] == pytest.approx(1e-3 / 1.5)


class CountingStep:
    """Wraps an optimiser's ``step`` to count the calls."""

    def __init__(self, optimizer: torch.optim.Optimizer) -> None:
        self.calls = 0
        self.inner = optimizer.step
        optimizer.step = self  # type: ignore[method-assign]

    def __call__(self, *args: object, **kwargs: object) -> object:
        self.calls += 1
        return self.inner(*args, **kwargs)


def test_gradient_step_counts():
    st = coded_storage()
    st.data.normal_()  # finite, small values for real steps
    st.sigma.fill_(1.0)
    ppo = PPO(
        ActorCritic(5, 2, 1, (4,), (4,)), PPOConfig(num_learning_epochs=2, num_mini_batches=3)
    )
    est = EstimatorLearning(Estimator(3, 2, (4,)), EstimatorConfig(mini_batch_size=5, num_epochs=3))
    ppo_steps, est_steps = CountingStep(ppo.optimizer), CountingStep(est.optimizer)
    ppo.update(st)
    est.update(st)
    assert ppo_steps.calls == 2 * 3  # epochs x mini-batches
    assert est_steps.calls == 3 * (12 // 5)  # epochs x whole batches of 5 in 12 samples
