"""One training entry point: the CLI's path and the Ray path (``train_with_pool``) run the same
code, so what one does for a run (config file, upright curriculum, provenance) the other does too.
"""

import csv
import json
import tomllib
from types import SimpleNamespace

import pytest
import torch
from fakes import FAKE_UPRIGHT_PITCH

from unigait.client import open_session
from unigait.config import load_config

SMALL = [
    "env.num_envs=6",
    "runner.num_steps_per_env=4",
    "runner.save_interval=1",
    "policy.actor_hidden_dims=[16]",
    "policy.critic_hidden_dims=[16]",
    "estimator.hidden_dims=[16]",
    "estimator.mini_batch_size=8",
    "env.task.rewards.upright_curriculum.enabled=true",
]


def _cfg(log_dir, iterations):
    run = [f"runner.log_dir={json.dumps(str(log_dir))}", f"runner.max_iterations={iterations}"]
    return load_config(None, [*SMALL, *run])


def _start(overrides_toml: str) -> object:
    return tomllib.loads(overrides_toml)["rewards"]["upright_curriculum"].get("start")


def test_the_ray_path_starts_where_its_checkpoint_left_the_curriculum(fake_server, tmp_path):
    """Before the one entry point, ``train_with_pool`` left the upright curriculum at the
    server's default on ``init_from``; now it starts at the checkpoint's threshold like the CLI,
    and keeps logging the pool's server restarts."""
    pytest.importorskip("ray")  # unigait.ray imports it
    from unigait.ray.train import train_with_pool
    from unigait.runners import train

    address, servicer = fake_server
    first = tmp_path / "first"
    train(_cfg(first, 1), lambda c: open_session(address, c))
    assert _start(servicer.task_overrides[-1]) is None  # a fresh run: the server's default
    checkpoint = torch.load(first / "model_1.pt", map_location="cpu", weights_only=False)
    assert "git_commit" in checkpoint["provenance"]

    pool = SimpleNamespace(
        num_servers=1,
        cpus_per_server=1,
        addresses=[address],
        open_session=lambda c: open_session(address, c),
    )
    second = tmp_path / "second"
    history = train_with_pool(pool, _cfg(second, 2), init_from=first / "model_1.pt")
    assert _start(servicer.task_overrides[-1]) == FAKE_UPRIGHT_PITCH
    assert f"start = {FAKE_UPRIGHT_PITCH}" in (second / "config.toml").read_text()
    assert [h["server_restarts"] for h in history] == [0.0, 0.0]
    with (second / "progress.csv").open() as f:
        assert [row["iteration"] for row in csv.DictReader(f)] == ["1", "2"]
