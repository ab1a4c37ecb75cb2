"""Learning against the real server: rsl_rl's runner on the adapter, the Gymnasium vector env,
and the paper's learner improving quad velocity tracking (then exported to ONNX)."""

import numpy as np
import pytest
import torch
from gymnasium.vector import AutoresetMode
from rsl_rl.runners import OnPolicyRunner as RslOnPolicyRunner
from unigait.client import Client, SessionConfig, UnigaitError
from unigait.config import load_config
from unigait.env import TorchVecEnv
from unigait.env.gymnasium_env import UnigaitVectorEnv
from unigait.env.rsl_rl_env import RslRlVecEnv, rsl_rl_train_cfg
from unigait.export import export_mismatch, export_onnx
from unigait.modules import EstimatorActorPolicy
from unigait.runners import OnPolicyRunner, build_networks

QUAD_ONLY = "[modes]\nbiped_probability = 0.0\n"
STAND_STILL = "[commands]\nquad = { vx = [0.0, 0.0], vy = [0.0, 0.0], wz = [0.0, 0.0] }\n"


def test_rsl_rl_on_policy_runner_two_iterations(server):
    torch.manual_seed(0)
    env = RslRlVecEnv(TorchVecEnv.connect(server, SessionConfig(num_envs=16, seed=3)))
    try:
        obs = env.get_observations()
        assert obs["policy"].shape == (16, 159) and obs["critic"].shape == (16, 77)
        runner = RslOnPolicyRunner(env, rsl_rl_train_cfg(num_steps_per_env=8), None, "cpu")
        before = [p.clone() for p in runner.alg.actor.parameters()]
        runner.learn(num_learning_iterations=2)
        assert runner.current_learning_iteration == 1
        after = list(runner.alg.actor.parameters())
        assert any(not torch.equal(a, b) for a, b in zip(before, after, strict=True))
    finally:
        env.close()


def test_gymnasium_vector_env(server):
    short = "[env]\nepisode_length_s = 0.1\nrandom_initial_episode_step = false\n"
    env = UnigaitVectorEnv(server, SessionConfig(num_envs=4, seed=0, task_overrides_toml=short))
    try:
        assert env.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
        assert env.single_observation_space.shape == (53,)
        assert env.single_action_space.shape == (12,)
        assert env.observation_space.shape == (4, 53) and env.action_space.shape == (4, 12)
        obs_a, info = env.reset(seed=5)
        assert env.observation_space.contains(obs_a) and info["labels"].shape == (4, 14)
        obs_b, _ = env.reset(seed=6)
        obs_c, _ = env.reset(seed=5)
        np.testing.assert_array_equal(obs_a, obs_c)  # the seed decides the episode
        assert not np.array_equal(obs_a, obs_b)
        env.action_space.seed(0)
        ended = np.zeros(4, bool)
        for _ in range(5):
            obs, rew, term, trunc, info = env.step(env.action_space.sample() * 0.1)
            assert obs.shape == (4, 53) and obs.dtype == np.float32
            assert rew.shape == (4,) and term.dtype == bool and trunc.dtype == bool
            if "final_obs" in info:
                done = term | trunc
                np.testing.assert_array_equal(info["_final_obs"], done)
                for i in np.flatnonzero(done):
                    assert info["final_obs"][i].shape == (53,)
                ended |= done
        assert ended.all()  # 5-step episodes: everyone ended, with its final observation
    finally:
        env.close()


def test_learner_improves_quad_velocity_tracking(server, tmp_path):
    """The paper's learner (defaults: PPO + estimator, [512, 256, 128] nets, one torch thread) on
    flat ground in quad mode with the command pinned to zero: 128 envs x 24 steps, 12 iterations,
    seeds 1.

    Measured on the 2-core dev box (shared with a Rust build): 34 s for the 12 iterations
    (~1,300 env steps/s, time shares sim 30% / inference 6% / update 64%). The rollout mean of
    the weighted quad_tracking_lin_vel term (max 2 x 0.02 = 0.04 per step) rose from 0.0239
    (untrained policy, iteration 1) to 0.0344 (mean of iterations 10-12), +0.0105; the asserted
    +0.006 is first passed at iteration 4. With the default command ranges the term does not move
    in a run this short (256 envs: 0.0089 at iteration 1, 0.0097 at 40; walking at a commanded
    speed takes hundreds of iterations), so the test pins the command to zero: tracking it means
    standing still and staying up.
    """
    torch.manual_seed(1)
    torch.set_num_threads(1)
    cfg = load_config(None, ["runner.num_steps_per_env=24", "runner.quiet=true"])
    session = SessionConfig(num_envs=128, seed=1, task_overrides_toml=QUAD_ONLY + STAND_STILL)
    env = TorchVecEnv.connect(server, session)
    try:
        runner = OnPolicyRunner(env, cfg, tmp_path)
        history = runner.learn(12)
        # The checkpoints record the engine the session reported (decision record 0026).
        assert env.spec.physics_engine in ("rapier", "articulated")
        saved = torch.load(tmp_path / "model_latest.pt", weights_only=False)
        assert saved["physics_engine"] == env.spec.physics_engine
    finally:
        env.close()
    track = [h["step_reward/quad_tracking_lin_vel"] for h in history]
    assert all(h["biped_share"] == 0.0 for h in history)
    untrained, trained = track[0], float(np.mean(track[-3:]))
    print(f"quad_tracking_lin_vel per step: {untrained:.4f} -> {trained:.4f}; {track}")
    assert trained > untrained + 0.006, track
    # The trained policy exports to one ONNX graph that matches torch.
    out = tmp_path / "policy.onnx"
    export_onnx(runner.policy(), out)
    assert export_mismatch(runner.policy().eval(), out) <= 1e-5


def test_evaluate_runs_an_exported_policy(server, tmp_path):
    """``Evaluate`` with the fused ONNX graph of an untrained policy (2 trials on flat_quad)."""
    torch.manual_seed(0)
    actor_critic, estimator = build_networks(load_config(), 53, 14, 10, 12)
    out = tmp_path / "policy.onnx"
    export_onnx(EstimatorActorPolicy(estimator, actor_critic.actor), out)
    with Client(server) as client:
        try:
            result = client.evaluate(out.read_bytes(), "flat_quad", num_envs=2, seed=0)
        except UnigaitError as err:
            if err.code_name == "UNIMPLEMENTED":
                pytest.skip(f"this server build has no Evaluate yet: {err.details}")
            raise
    assert result.metrics and all(isinstance(v, float) for v in result.metrics.values())
    assert result.report_json.startswith("{")
