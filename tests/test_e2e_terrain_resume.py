"""A curriculum run resumed from its checkpoint starts its envs on the levels they had reached,
not on the drawn starting levels again (the real server, two tiny trainings)."""

import os
import subprocess
import sys
from pathlib import Path

import torch
from unigait.client import SessionConfig, open_session
from unigait.config import load_config
from unigait.runners.training import train

TINY = [
    "env.num_envs=20",
    "env.terrain='curriculum'",
    "env.terrain_level=1",
    "policy.actor_hidden_dims=[16]",
    "policy.critic_hidden_dims=[16]",
    "estimator.hidden_dims=[16]",
    "estimator.mini_batch_size=8",
    "runner.num_steps_per_env=4",
    "runner.save_interval=1",
    "runner.plot_interval=1000",
    "runner.quiet=true",
]


def test_a_resumed_curriculum_run_starts_on_its_checkpoints_levels(server: str, tmp_path: Path):
    cfg = load_config(None, [*TINY, "runner.max_iterations=2", f"runner.log_dir='{tmp_path}'"])
    train(cfg, lambda c: open_session(server, c))
    checkpoint = tmp_path / "model_2.pt"
    state = torch.load(checkpoint, weights_only=False)
    # Every env's level at the end of the last rollout, within the drawn range 0..=1 plus what
    # two short rollouts could move (nothing: 16 steps end no episode).
    assert len(state["terrain_levels"]) == 20
    assert set(state["terrain_levels"]) <= {0, 1}
    # Levels the drawn range (0..=1) cannot give: only a carried-over level puts an env there.
    carried = [9 - i % 5 for i in range(20)]
    state["terrain_levels"] = carried
    torch.save(state, checkpoint)

    asked: list[SessionConfig] = []
    started: list[list[int]] = []

    def recording(config: SessionConfig):
        asked.append(config)
        session = open_session(server, config)
        started.append([int(x) for x in session.initial.terrain_level])
        return session

    cfg = load_config(None, [*TINY, "runner.max_iterations=3", f"runner.log_dir='{tmp_path}'"])
    train(cfg, recording, resume=checkpoint)
    assert list(asked[0].terrain_levels) == carried
    assert started[0] == carried
    # With another number of envs the columns move: the levels are not carried.
    cfg = load_config(
        None,
        [*TINY, "env.num_envs=10", "runner.max_iterations=4", f"runner.log_dir='{tmp_path}'"],
    )
    asked.clear()
    train(cfg, recording, resume=tmp_path / "model_3.pt")
    assert asked[0].terrain_levels == ()


def test_a_resumed_run_with_a_level_per_mode_starts_each_mode_where_it_was(
    server: str, tmp_path: Path
):
    """Decision record 0036: the checkpoint holds both modes' levels and hands them back."""
    per_mode = [*TINY, "env.task.terrain_curriculum.per_mode_levels=true"]
    cfg = load_config(None, [*per_mode, "runner.max_iterations=2", f"runner.log_dir='{tmp_path}'"])
    train(cfg, lambda c: open_session(server, c))
    checkpoint = tmp_path / "model_2.pt"
    state = torch.load(checkpoint, weights_only=False)
    # No episode ended in 8 steps: both modes are still on each env's drawn level.
    pairs = state["terrain_mode_levels"]
    assert pairs == [level for level in state["terrain_levels"] for _ in range(2)]
    carried = [x for i in range(20) for x in (i % 3, 9 - i % 5)]  # (quad, biped) per env
    state["terrain_mode_levels"] = carried
    torch.save(state, checkpoint)

    asked: list[SessionConfig] = []
    initial: list = []

    def recording(config: SessionConfig):
        asked.append(config)
        session = open_session(server, config)
        initial.append(session.initial)
        return session

    cfg = load_config(None, [*per_mode, "runner.max_iterations=3", f"runner.log_dir='{tmp_path}'"])
    train(cfg, recording, resume=checkpoint)
    assert list(asked[0].terrain_mode_levels) == carried
    first = initial[0]
    assert first.mode_levels.flatten().tolist() == carried
    # Each env stands on the level of the mode it starts in (mode 1 is biped: the second).
    for i, (mode, tile) in enumerate(zip(first.mode, first.terrain_level, strict=True)):
        assert tile == carried[2 * i + int(mode == 1)], i
    resumed = torch.load(tmp_path / "model_3.pt", weights_only=False)
    assert len(resumed["terrain_mode_levels"]) == 40


def test_a_run_on_a_grid_of_its_own_logs_its_columns(server: str, tmp_path: Path):
    """``env.terrain_columns`` builds the grid the run asks for, and the log counts its types."""
    columns = "env.terrain_columns=['stairs_down', 'slope_up', 'slope_up']"
    cfg = load_config(
        None, [*TINY, columns, "runner.max_iterations=1", f"runner.log_dir='{tmp_path}'"]
    )
    specs = []

    def recording(config: SessionConfig):
        session = open_session(server, config)
        specs.append(session.spec)
        return session

    train(cfg, recording)
    assert specs[0].terrain_columns == ("stairs_down", "slope_up", "slope_up")
    header = (tmp_path / "progress.csv").read_text().splitlines()[0].split(",")
    levels = {h for h in header if h.startswith("terrain_level/") and h.count("/") == 1}
    assert levels == {
        "terrain_level/stairs_down",
        "terrain_level/slope_up",
        "terrain_level/quad",
        "terrain_level/biped",
    }
    state = torch.load(tmp_path / "model_1.pt", weights_only=False)
    assert state["terrain_columns"] == ["stairs_down", "slope_up", "slope_up"]


RECIPE = """
description = "two tiny curriculum stages on the real server"

[[stages]]
name = "first"
[stages.stop]
iterations = 2
[stages.env]
num_envs = 20
terrain = "curriculum"
terrain_level = 1
[stages.policy]
actor_hidden_dims = [16]
critic_hidden_dims = [16]
[stages.estimator]
hidden_dims = [16]
mini_batch_size = 8
[stages.runner]
num_steps_per_env = 4
save_interval = 1
plot_interval = 1000
quiet = true

[[stages]]
name = "second"
start = "previous"
carry = "all"
[stages.stop]
iterations = 1
"""


def test_a_recipes_next_stage_starts_on_the_levels_its_first_stage_reached(
    server: str, server_bin: Path, tmp_path: Path
):
    recipe = tmp_path / "tiny.toml"
    recipe.write_text(RECIPE)
    run = tmp_path / "run"
    command = [sys.executable, "-m", "unigait", "train", "--server", server]
    command += ["--recipe", str(recipe), "--log-dir", str(run)]
    env = {**os.environ, "UNIGAIT_SERVER_BIN": str(server_bin)}
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    first = torch.load(run / "01_first" / "model_2.pt", weights_only=False)
    assert len(first["terrain_levels"]) == 20
    mean = sum(first["terrain_levels"]) / 20
    source = run / "01_first" / "model_2.pt"
    line = f"stage 02_second: envs start on the terrain levels of {source} (mean {mean:.2f})"
    assert line in done.stderr, done.stderr
