"""GAE, the time-out bootstrap, the KL and the adaptive learning-rate rule, by hand."""

import pytest
import torch

from unigait.algorithms import PPO, PPOConfig, adaptive_learning_rate, bound_loss, gaussian_kl
from unigait.modules import ActorCritic
from unigait.storage import RolloutStorage, bootstrap_time_outs, compute_gae


def test_time_out_bootstrap_skips_terminations():
    # Env 0 terminated (final value 10 must be ignored), env 1 timed out (final value 4),
    # env 2 both terminated and truncated in the same step (a termination: not bootstrapped).
    rewards = torch.tensor([1.0, 2.0, 3.0, 4.0])
    terminated = torch.tensor([True, False, True, False])
    truncated = torch.tensor([False, True, True, False])
    ids = torch.tensor([0, 1, 2])
    final_values = torch.tensor([10.0, 4.0, 7.0])
    out = bootstrap_time_outs(rewards, terminated, truncated, ids, final_values, gamma=0.9)
    assert out.tolist() == pytest.approx([1.0, 2.0 + 0.9 * 4.0, 3.0, 4.0])
    assert rewards.tolist() == [1.0, 2.0, 3.0, 4.0]  # input untouched


def test_gae_hand_computed():
    gamma, lam = 0.9, 0.5
    # Env 0: no episode end. Env 1: terminated after step 0, timed out after step 1 with
    # V(final) = 4 (reward 2 -> 2 + 0.9 * 4 = 5.6), running on at step 2.
    rewards = torch.tensor([[1.0, 1.0], [2.0, 5.6], [3.0, 3.0]])
    values = torch.tensor([[0.5, 0.5], [1.0, 1.0], [1.5, 1.5]])
    dones = torch.tensor([[0.0, 1.0], [0.0, 1.0], [0.0, 0.0]])
    last = torch.tensor([2.0, 2.0])
    adv, ret = compute_gae(rewards, values, dones, last, gamma, lam)
    # Env 0: delta2 = 3 + 0.9*2 - 1.5 = 3.3; delta1 = 2 + 0.9*1.5 - 1 = 2.35;
    #        A1 = 2.35 + 0.45*3.3 = 3.835; delta0 = 1 + 0.9*1 - 0.5 = 1.4; A0 = 1.4 + 0.45*3.835.
    # Env 1: A2 = 3.3; A1 = 5.6 - 1 = 4.6 (done: nothing flows back); A0 = 1 - 0.5 = 0.5.
    expected = torch.tensor([[3.12575, 0.5], [3.835, 4.6], [3.3, 3.3]])
    torch.testing.assert_close(adv, expected)
    torch.testing.assert_close(ret, expected + values)


def test_gaussian_kl_hand_value():
    one = torch.ones(1, 1)
    kl = gaussian_kl(0 * one, one, one, 2 * one)
    # ln(2 + 1e-5) + (1 + 1) / 8 - 0.5
    assert kl.item() == pytest.approx(0.6931522 + 0.25 - 0.5, abs=1e-6)
    same = gaussian_kl(one, one, one, one)
    assert same.item() == pytest.approx(1e-5, abs=1e-6)  # only the 1e-5 guard remains


@pytest.mark.parametrize(
    ("lr", "kl", "expected"),
    [
        (1e-3, 0.03, 1e-3 / 1.5),  # KL > 2 kl*: shrink
        (1e-3, 0.004, 1.5e-3),  # 0 < KL < kl*/2: grow
        (1e-3, 0.01, 1e-3),  # in the band: keep
        (1e-3, 0.02, 1e-3),  # exactly 2 kl*: keep
        (1e-3, 0.005, 1e-3),  # exactly kl*/2: keep
        (1e-3, 0.0, 1e-3),  # zero KL: keep
        (1.2e-5, 1.0, 1e-5),  # floor
        (8e-3, 1e-4, 1e-2),  # ceiling
    ],
)
def test_adaptive_learning_rate_rule(lr, kl, expected):
    assert adaptive_learning_rate(lr, kl, desired_kl=0.01) == pytest.approx(expected)


def test_ppo_update_applies_the_rule_per_mini_batch():
    torch.manual_seed(0)
    steps, envs = 4, 8
    ac = ActorCritic(6, 5, 2, (16,), (16,), init_noise_std=1.0)
    st = RolloutStorage(steps, envs, 6, 4, 5, 3, 2)
    for _ in range(steps):
        obs = torch.randn(envs, 6)
        with torch.no_grad():
            actions, log_prob, dist = ac.act(obs)
            values = ac.value(torch.randn(envs, 5))
        st.add(
            obs,
            torch.randn(envs, 5),
            torch.randn(envs, 3),
            actions,
            log_prob,
            dist.mean,
            dist.stddev,
            values,
            torch.randn(envs),
            torch.zeros(envs),
        )
    st.compute_returns(torch.zeros(envs), 0.99, 0.95)
    assert st.advantages.mean().abs() < 1e-5 and (st.advantages.std() - 1).abs() < 1e-4
    ppo = PPO(ac, PPOConfig(learning_rate=1e-3, num_learning_epochs=1, num_mini_batches=2))
    stats = ppo.update(st)
    # The first mini-batch sees the rollout policy itself: KL ~1e-5*dims < kl*/2, so lr grows.
    assert ppo.learning_rate >= 1.5e-3 - 1e-12
    assert stats["learning_rate"] == ppo.learning_rate
    assert all(torch.isfinite(torch.tensor(v)) for v in stats.values())


def _narrowing_rollout(ac: ActorCritic) -> RolloutStorage:
    """Actions near the mean earned +1 and far ones -1: an update narrows the std."""
    steps, envs = 4, 8
    st = RolloutStorage(steps, envs, 6, 4, 5, 3, 1)
    obs = torch.full((envs, 6), 0.5)
    actions = torch.tensor([0.1, -0.1, 2.0, -2.0] * 2).unsqueeze(1)
    rewards = torch.where(actions.abs().squeeze(1) < 1.0, 1.0, -1.0)
    with torch.no_grad():
        dist = ac.distribution(obs)
        log_prob = dist.log_prob(actions).sum(-1)
    for _ in range(steps):
        st.add(
            obs,
            torch.full((envs, 5), 0.5),
            torch.zeros(envs, 3),
            actions,
            log_prob,
            dist.mean,
            dist.stddev,
            torch.zeros(envs),
            rewards,
            torch.ones(envs),
        )
    st.compute_returns(torch.zeros(envs), 0.99, 0.95)
    return st


@pytest.mark.parametrize("floor", [0.0, 0.95])
def test_the_std_floor_holds_where_the_update_would_narrow(floor: float) -> None:
    torch.manual_seed(0)
    ac = ActorCritic(6, 5, 1, (8,), (8,), init_noise_std=1.0)
    cfg = PPOConfig(learning_rate=1e-2, schedule="fixed", entropy_coef=0.0, min_action_std=floor)
    stats = PPO(ac, cfg).update(_narrowing_rollout(ac))
    if floor == 0.0:
        assert stats["action_std"] < 0.95
    else:
        assert stats["action_std"] == pytest.approx(0.95, abs=1e-6)


def test_bound_loss_on_known_numbers() -> None:
    # Bound 10: row 1 pays (12 - 10)^2 = 4, row 2 pays (11.5 - 10)^2 = 2.25; mean 3.125.
    mu = torch.tensor([[12.0, -3.0], [0.0, -11.5]])
    assert bound_loss(mu, 10.0).item() == pytest.approx(3.125)
    assert bound_loss(mu, 20.0).item() == 0.0


def _mean_after_one_update(coef: float) -> tuple[float, dict[str, float]]:
    """The actor's mean (5 for every input) after one update on a rollout of equal rewards.

    Equal rewards leave every advantage at 0 and the entropy bonus is off, so only the bound
    loss (bound 1, weight ``coef``) can move the mean.
    """
    torch.manual_seed(0)
    ac = ActorCritic(6, 5, 1, (8,), (8,), init_noise_std=1.0)
    last = ac.actor[-1]
    assert isinstance(last, torch.nn.Linear)
    with torch.no_grad():
        last.weight.zero_()
        last.bias.fill_(5.0)
    st = _narrowing_rollout(ac)
    st.rewards.fill_(1.0)
    st.compute_returns(torch.zeros(8), 0.99, 0.95)
    cfg = PPOConfig(
        learning_rate=1e-2,
        schedule="fixed",
        entropy_coef=0.0,
        num_learning_epochs=1,
        num_mini_batches=1,
        action_mean_bound=1.0,
        bound_loss_coef=coef,
    )
    stats = PPO(ac, cfg).update(st)
    with torch.no_grad():
        mean = float(ac.actor(torch.full((1, 6), 0.5)))
    return mean, stats


def test_the_bound_loss_alone_pulls_an_outlying_mean_in() -> None:
    free, free_stats = _mean_after_one_update(0.0)
    assert free == 5.0 and "bound_loss" not in free_stats
    bounded, stats = _mean_after_one_update(1.0)
    # (5 - 1)^2 = 16 before the one Adam step. Adam's first step moves each parameter by the
    # rate (1e-2) against its gradient's sign: the bias, and each zeroed weight by the sign of
    # its hidden unit, so the mean falls by 1e-2 (1 + sum |h_i|) over the 8 units, < 0.1.
    assert stats["bound_loss"] == pytest.approx(16.0)
    assert 4.8 < bounded < 5.0 - 1e-3
