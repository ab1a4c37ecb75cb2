"""Config loading/overrides and the fused ONNX export."""

import dataclasses
import tomllib

import numpy as np
import onnx
import pytest
import torch

from unigait.config import (
    TrainConfig,
    load_config,
    parse_override,
    resume_upright_curriculum,
    with_task_setting,
)
from unigait.export import export_mismatch, export_onnx, load_policy
from unigait.modules import EstimatorActorPolicy
from unigait.runners import build_networks


def test_config_overrides_and_toml(tmp_path):
    cfg = load_config(
        None,
        [
            "ppo.learning_rate=3e-4",
            "env.num_envs=64",
            'env.servers=["a:1", "b:2"]',
            "runner.log_dir=runs/x",
        ],
    )
    assert cfg.ppo.learning_rate == 3e-4 and cfg.env.num_envs == 64
    assert cfg.env.servers == ("a:1", "b:2") and cfg.runner.log_dir == "runs/x"
    assert parse_override("env.terrain=flat") == ("env", "terrain", "flat")
    with pytest.raises(KeyError, match="learning_rat"):
        load_config(None, ["ppo.learning_rat=1"])
    with pytest.raises(KeyError, match="unknown config section"):
        load_config(None, ["nope.x=1"])
    path = tmp_path / "c.toml"
    path.write_text(TrainConfig().to_toml())
    assert load_config(path) == TrainConfig()
    assert (
        TrainConfig().ppo.num_mini_batches == 4 and TrainConfig().estimator.mini_batch_size == 768
    )


def test_task_setting_is_merged_into_the_fragment_and_a_resume_keeps_the_curriculum():
    fragment = "[rewards.upright_curriculum]\nenabled = true\n\n[env]\ndecimation = 4\n"
    merged = tomllib.loads(with_task_setting(fragment, "rewards.upright_curriculum.start", 1.3))
    assert merged == {
        "rewards": {"upright_curriculum": {"enabled": True, "start": 1.3}},
        "env": {"decimation": 4},
    }
    assert tomllib.loads(with_task_setting("", "modes.biped_probability", 1.0)) == {
        "modes": {"biped_probability": 1.0}
    }

    off = load_config(None, [])
    on = dataclasses.replace(off, env=dataclasses.replace(off.env, task_overrides_toml=fragment))
    resumed = resume_upright_curriculum(on, {"upright_pitch": 1.35})
    task = tomllib.loads(resumed.env.task_overrides_toml)
    assert task["rewards"]["upright_curriculum"] == {"enabled": True, "start": 1.35}
    assert task["env"] == {"decimation": 4}
    assert dataclasses.replace(resumed.env, task_overrides_toml=fragment) == on.env
    # Nothing to carry: no threshold in the checkpoint, or the run has no curriculum.
    assert resume_upright_curriculum(on, {}) is on
    assert resume_upright_curriculum(off, {"upright_pitch": 1.35}) is off


def test_onnx_export_matches_torch(tmp_path):
    torch.manual_seed(0)
    cfg = TrainConfig()
    ac, est = build_networks(cfg, 53, 14, 10, 12)
    with torch.no_grad():  # move the std-free actor away from its init a little
        for p in ac.actor.parameters():
            p.add_(0.05 * torch.randn_like(p))
    ckpt = tmp_path / "model.pt"
    torch.save(
        {
            "config": cfg.to_dict(),
            "actor_critic": ac.state_dict(),
            "estimator": est.state_dict(),
            "dims": {
                "obs_dim": 53,
                "label_dim": 14,
                "privileged_dim": 10,
                "num_actions": 12,
                "history_length": 3,
            },
        },
        ckpt,
    )
    policy, dims = load_policy(ckpt)
    assert isinstance(policy, EstimatorActorPolicy) and dims["history_length"] == 3
    out = tmp_path / "policy.onnx"
    export_onnx(policy, out)
    model = onnx.load(out)
    onnx.checker.check_model(model)
    (inp,) = model.graph.input
    (outp,) = model.graph.output
    assert inp.name == "obs_history" and outp.name == "actions"
    dims_in = [d.dim_param or d.dim_value for d in inp.type.tensor_type.shape.dim]
    dims_out = [d.dim_param or d.dim_value for d in outp.type.tensor_type.shape.dim]
    assert dims_in == ["batch", 3, 53] and dims_out == ["batch", 12]
    assert len(model.graph.input) == 1  # estimator and actor are one graph
    for batch in (1, 257):
        assert export_mismatch(policy, out, batch=batch, seed=batch) <= 1e-5
    # The fused graph equals estimator then actor by hand.
    x = torch.randn(4, 3, 53)
    flat = x.flatten(1)
    by_hand = ac.actor(torch.cat([flat, est(flat)], -1))
    np.testing.assert_allclose(policy(x).detach(), by_hand.detach(), atol=1e-6)


def test_presets_load_and_each_stage_can_start_from_the_one_before():
    from unigait import presets

    cfgs = {name: load_config(None, presets.overrides_of(name)) for name in presets.names()}
    assert set(cfgs) >= {"quad_flat", "unified_flat", "unified_terrain"}
    # quad_flat keeps Table III (its shipped M1 policy was trained so).
    assert list(cfgs["quad_flat"].policy.actor_hidden_dims) == [512, 256, 128]
    # unified_terrain starts from a unified_flat checkpoint: the networks must match.
    flat, terrain = cfgs["unified_flat"].policy, cfgs["unified_terrain"].policy
    assert list(flat.actor_hidden_dims) == list(terrain.actor_hidden_dims) == [256, 128, 64]
    assert list(flat.critic_hidden_dims) == list(terrain.critic_hidden_dims) == [256, 128, 64]
    assert cfgs["unified_flat"].ppo == cfgs["quad_flat"].ppo  # the paper's PPO everywhere
