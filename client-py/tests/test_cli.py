"""``python -m unigait`` train (with --resume), export and evaluate against the fake server."""

import csv
import json
import tomllib

from fakes import FAKE_UPRIGHT_PITCH

from unigait.cli import main

SMALL = [
    "--set", "runner.num_steps_per_env=4",
    "--set", "policy.actor_hidden_dims=[16]",
    "--set", "policy.critic_hidden_dims=[16]",
    "--set", "estimator.hidden_dims=[16]",
    "--set", "estimator.mini_batch_size=8",
    "--set", "runner.save_interval=1",
]  # fmt: skip


def test_train_resume_export_evaluate(fake_server, tmp_path, capsys):
    address, servicer = fake_server
    log_dir = tmp_path / "run"
    args = ["train", "--server", address, "--num-envs", "6", "--log-dir", str(log_dir), *SMALL]
    assert main([*args, "--iterations", "2", "--quad-only"]) == 0
    out = capsys.readouterr().out
    assert "Learning" not in out and "quad_tracking_lin_vel" in out  # full block per iteration
    assert (log_dir / "model_2.pt").is_file() and (log_dir / "config.toml").is_file()
    assert "biped_probability = 0.0" in (log_dir / "config.toml").read_text()
    assert not servicer.sims  # the session was closed

    assert main([*args, "--iterations", "3", "--resume", str(log_dir / "model_2.pt")]) == 0
    assert "resumed from" in capsys.readouterr().out
    with (log_dir / "progress.csv").open() as f:
        assert [row["iteration"] for row in csv.DictReader(f)] == ["1", "2", "3"]

    onnx_path = tmp_path / "policy.onnx"
    assert (
        main(["export", "--checkpoint", str(log_dir / "model_3.pt"), "--out", str(onnx_path)]) == 0
    )
    report = tmp_path / "report.json"
    rrd = tmp_path / "run.rrd"
    evaluate = ["evaluate", "--server", address, "--policy", str(onnx_path)]
    options = ["--scenario", "flat_quad", "--num-envs", "5", "--report", str(report)]
    code = main([*evaluate, *options, "--record", str(rrd)])
    assert code == 0
    assert "policy_bytes" in capsys.readouterr().out
    assert json.loads(report.read_text()) == {"scenario": "flat_quad", "physics_engine": "rapier"}
    assert rrd.read_bytes() == b"RRD"


def test_a_stage_starts_the_upright_curriculum_where_its_checkpoint_left_it(fake_server, tmp_path):
    address, servicer = fake_server
    curriculum = "env.task.rewards.upright_curriculum.enabled=true"
    args = ["train", "--server", address, "--num-envs", "6", *SMALL, "--set", curriculum]
    first = tmp_path / "first"
    assert main([*args, "--log-dir", str(first), "--iterations", "1"]) == 0

    def start(overrides: str) -> object:
        return tomllib.loads(overrides)["rewards"]["upright_curriculum"].get("start")

    assert start(servicer.task_overrides[-1]) is None  # a fresh run: the server's default
    for flag in ("--resume", "--init-from"):
        stage = ["--log-dir", str(tmp_path / flag.strip("-")), "--iterations", "2"]
        assert main([*args, *stage, flag, str(first / "model_1.pt")]) == 0
        assert start(servicer.task_overrides[-1]) == FAKE_UPRIGHT_PITCH, flag


def test_server_errors_become_exit_code_2(fake_server, tmp_path, capsys):
    address, _ = fake_server
    empty = tmp_path / "empty.onnx"
    empty.write_bytes(b"")
    assert main(["evaluate", "--server", address, "--policy", str(empty), "--scenario", "x"]) == 2
    assert "INVALID_ARGUMENT" in capsys.readouterr().err


def test_server_args_reach_every_ray_server(monkeypatch, tmp_path):
    """`--server-arg` is how a pod's memory limit bounds its server (deploy/check.sh)."""
    import unigait.ray

    got: dict[str, object] = {}
    monkeypatch.setattr(unigait.ray, "train_on_ray", lambda cfg, **kwargs: got.update(kwargs))
    args = ["train", "--ray", "auto", "--log-dir", str(tmp_path / "run")]
    # The `=` form: argparse takes a separate value starting with `--` for another option.
    args += ["--server-arg=--max-total-envs=8192", "--server-arg=--max-sessions=4"]
    assert main(args) == 0
    assert got["pool_options"] == {"extra_args": ["--max-total-envs=8192", "--max-sessions=4"]}
