"""Torch env, history, rsl_rl adapter and Gymnasium vector env over the numpy fake session."""

import gymnasium as gym
import numpy as np
import torch
from fakes import FakeSession
from gymnasium.vector import AutoresetMode

from unigait.client import SessionConfig
from unigait.env import ObservationHistory, TorchVecEnv
from unigait.env.gymnasium_env import UnigaitVectorEnv
from unigait.env.rsl_rl_env import RslRlVecEnv, rsl_rl_train_cfg


def test_history_push_and_reset():
    h = ObservationHistory(2, 3, 1)
    h.reset(torch.tensor([[1.0], [5.0]]))
    h.push(torch.tensor([[2.0], [6.0]]))
    h.push(torch.tensor([[3.0], [0.0]]), reset=torch.tensor([False, True]))
    assert h.flat.tolist() == [[3.0, 2.0, 1.0], [0.0, 0.0, 0.0]]  # newest first; env 1 refilled


def test_torch_env_step_and_critic_input():
    env = TorchVecEnv(FakeSession(5))
    assert env.last.obs.shape == (5, 53) and env.last.critic_obs.shape == (5, 77)
    step = env.step(torch.zeros(5, 12))
    assert step.final_env_ids.tolist() == [4]  # env 4 started at age 4 of 5
    assert step.truncated[4] and not step.terminated[4]
    assert step.final_obs[0, 0] == 5.0  # its last observation, before the reset
    assert step.obs[4, 0] == 0.0  # the new episode's first observation
    assert step.final_critic_obs.shape == (1, 77)
    env.close()
    assert env.session.closed


def test_rsl_rl_adapter_contract():
    env = RslRlVecEnv(TorchVecEnv(FakeSession(8)))
    obs = env.get_observations()
    assert set(obs.keys()) == {"policy", "critic"}
    assert obs["policy"].shape == (8, 159) and obs["critic"].shape == (8, 77)
    assert env.num_actions == 12 and env.max_episode_length == 5
    logs = []
    for _ in range(5):
        obs, rew, dones, extras = env.step(torch.zeros(8, 12))
        assert rew.shape == (8,) and dones.shape == (8,)
        assert extras["time_outs"].dtype == torch.bool
        logs.append(extras["log"])
    assert any("Episode_Reward/quad_tracking_lin_vel" in log for log in logs)
    # The policy group restarts the history of reset envs.
    ended = dones.bool()
    p = obs["policy"].view(8, 3, 53)
    assert torch.equal(p[ended, 1], p[ended, 0]) and torch.equal(p[ended, 2], p[ended, 0])
    cfg = rsl_rl_train_cfg()
    assert cfg["obs_groups"] == {"actor": ["policy"], "critic": ["critic"]}


def test_gymnasium_vector_env():
    env = UnigaitVectorEnv(
        "",
        SessionConfig(num_envs=6, seed=1),
        session_factory=lambda cfg: FakeSession(cfg.num_envs, cfg.seed),
    )
    assert env.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert isinstance(env.single_observation_space, gym.spaces.Box)
    assert env.observation_space.shape == (6, 53) and env.action_space.shape == (6, 12)
    obs, info = env.reset(seed=1)
    assert env.observation_space.contains(obs)
    assert info["labels"].shape == (6, 14)
    obs, info = env.reset(seed=7)  # a new seed re-creates the session
    assert obs[0, 2] == 7.0
    obs, rew, term, trunc, info = env.step(env.action_space.sample())
    assert obs.shape == (6, 53) and rew.dtype == np.float32
    assert term.dtype == bool and trunc.dtype == bool
    assert trunc[4] and info["_final_obs"][4] and info["final_obs"][4][0] == 5.0
    assert info["final_info"]["episode_length"][4] == 5
    assert info["final_obs"][0] is None
    env.close()


def test_gymnasium_wrappers_accept_the_env():
    env = UnigaitVectorEnv(
        "",
        SessionConfig(num_envs=6, seed=1),
        session_factory=lambda cfg: FakeSession(cfg.num_envs, cfg.seed),
    )
    wrapped = gym.wrappers.vector.RecordEpisodeStatistics(env)
    wrapped.reset(seed=1)
    lengths = []
    for _ in range(6):
        *_, info = wrapped.step(wrapped.action_space.sample())
        if "episode" in info:
            lengths += info["episode"]["l"][info["_episode"]].tolist()
    assert 5 in lengths  # a full fake episode, counted by Gymnasium's own wrapper
    wrapped.close()
