"""Config loading/overrides and the fused ONNX export."""

import dataclasses
import json
import tomllib
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from unigait.config import (
    TrainConfig,
    apply,
    checkpoint_engine,
    checkpoint_engine_overrides,
    load_config,
    parse_override,
    resume_upright_curriculum,
    with_task_setting,
)
from unigait.export import export_mismatch, export_onnx, load_policy, with_metadata
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


def test_task_setting_is_merged_into_the_table_and_a_resume_keeps_the_curriculum():
    table = {"rewards": {"upright_curriculum": {"enabled": True}}, "env": {"decimation": 4}}
    assert with_task_setting(table, "rewards.upright_curriculum.start", 1.3) == {
        "rewards": {"upright_curriculum": {"enabled": True, "start": 1.3}},
        "env": {"decimation": 4},
    }
    assert table == {"rewards": {"upright_curriculum": {"enabled": True}}, "env": {"decimation": 4}}
    assert with_task_setting({}, "modes.biped_probability", 1.0) == {
        "modes": {"biped_probability": 1.0}
    }

    off = load_config(None, [])
    on = dataclasses.replace(off, env=dataclasses.replace(off.env, task=table))
    resumed = resume_upright_curriculum(on, {"upright_pitch": 1.35})
    task = tomllib.loads(resumed.env.task_toml())
    assert task["rewards"]["upright_curriculum"] == {"enabled": True, "start": 1.35}
    assert task["env"] == {"decimation": 4}
    assert dataclasses.replace(resumed.env, task=table) == on.env
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
    policy, dims, engine = load_policy(ckpt)
    assert isinstance(policy, EstimatorActorPolicy) and dims["history_length"] == 3
    assert engine == "rapier"  # a checkpoint from before engines were recorded, its task silent
    out = tmp_path / "policy.onnx"
    export_onnx(policy, out, physics_engine="articulated")
    model = onnx.load(out)
    onnx.checker.check_model(model)
    # The engine it trained on, as the onnx package reads the appended metadata entry.
    assert {p.key: p.value for p in model.metadata_props} == {
        "unigait.physics_engine": "articulated"
    }
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


def test_the_task_is_a_table_set_by_key_and_an_old_checkpoints_string_still_reads():
    cfg = load_config(
        None,
        [
            "env.task.rewards.weights.biped_body_contact=-3.0",
            "env.task.rewards.upright_pitch=1.45",
        ],
    )
    assert cfg.env.task == {
        "rewards": {"weights": {"biped_body_contact": -3.0}, "upright_pitch": 1.45}
    }
    assert tomllib.loads(cfg.env.task_toml()) == cfg.env.task
    assert TrainConfig().env.task_toml() == ""
    # The config (with its task table) survives its own TOML.
    assert apply(TrainConfig(), tomllib.loads(cfg.to_toml())) == cfg
    # A checkpoint written before the task was a table carries a TOML string: read as one.
    old = {"env": {"task_overrides_toml": "[modes]\nbiped_probability = 0.0\n", "num_envs": 8}}
    assert apply(TrainConfig(), old).env.task == {"modes": {"biped_probability": 0.0}}
    with pytest.raises(TypeError, match=r"env\.task must be a table"):
        apply(TrainConfig(), {"env": {"task": 3}})
    # A list's items are checked where the config is read, not later in the protobuf.
    columns = apply(TrainConfig(), {"env": {"terrain_columns": ["slope_up", "obstacles"]}})
    assert columns.env.terrain_columns == ("slope_up", "obstacles")
    with pytest.raises(TypeError, match=r"terrain_columns must hold strs"):
        apply(TrainConfig(), {"env": {"terrain_columns": ["slope_up", 3]}})
    with pytest.raises(TypeError, match=r"actor_hidden_dims must hold ints"):
        apply(TrainConfig(), {"policy": {"actor_hidden_dims": [256, "wide"]}})


def test_a_checkpoint_names_the_engine_it_trained_on_or_its_task_or_rapier():
    task = {"physics": {"engine": "articulated"}}
    assert checkpoint_engine({"physics_engine": "articulated", "config": {}}) == "articulated"
    assert checkpoint_engine({"config": {"env": {"task": task}}}) == "articulated"
    # Recorded wins over the task's table; nothing said means a checkpoint from rapier days.
    recorded = {"physics_engine": "rapier", "config": {"env": {"task": task}}}
    assert checkpoint_engine(recorded) == "rapier"
    assert checkpoint_engine({"physics_engine": "", "config": {"env": {"task": {}}}}) == "rapier"
    assert checkpoint_engine_overrides({}) == 'physics.engine = "rapier"'


def test_metadata_is_appended_as_protobuf_field_14(tmp_path):
    """Long values need multi-byte varints; the onnx package reads every entry back in order."""
    model = onnx.helper.make_model(onnx.helper.make_graph([], "g", [], []))
    raw = model.SerializeToString()
    stamped = with_metadata(with_metadata(raw, "a", "x" * 300), "unigait.physics_engine", "rapier")
    assert stamped.startswith(raw)
    back = onnx.load_from_string(stamped)
    assert [(p.key, len(p.value)) for p in back.metadata_props] == [
        ("a", 300),
        ("unigait.physics_engine", 6),
    ]


def test_every_shipped_policy_names_the_engine_its_reports_ran_on():
    """The server evaluates a shipped policy on the engine it names: the one its reports were
    measured on (reports from before reports named the engine ran on rapier)."""
    shipped = sorted((Path(__file__).resolve().parents[2] / "assets" / "policies").iterdir())
    assert len(shipped) >= 5
    for folder in shipped:
        stamp = {p.key: p.value for p in onnx.load(folder / "policy.onnx").metadata_props}
        engine = stamp.get("unigait.physics_engine")
        ran_on = {
            json.loads(r.read_text()).get("physics_engine", "rapier")
            for r in (folder / "reports").glob("*.json")
            if not r.name.startswith("sim2sim_")
        }
        assert ran_on == {engine}, (folder.name, engine, ran_on)
