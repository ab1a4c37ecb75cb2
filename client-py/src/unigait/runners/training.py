"""The one training entry point: ``python -m unigait train`` and the Ray path both call it.

Where the servers are is the caller's business (addresses of running servers, a Ray pool);
everything else about a run is here: the upright curriculum carried over from a start
checkpoint, seeds and threads, the run folder and its ``config.toml``, resuming or initialising
the networks, the stage line and provenance the checkpoints keep, and the learning itself.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from unigait.client import SessionConfig, SessionLike
from unigait.config import (
    TrainConfig,
    resume_upright_curriculum,
    resumed_mode_levels,
    resumed_terrain_levels,
    session_config,
)
from unigait.env import TorchVecEnv
from unigait.env.terrain_stats import grid_change
from unigait.live_view import LiveView, ViewTarget, robot_drawer
from unigait.provenance import git_commit
from unigait.runners.on_policy_runner import OnPolicyRunner


def train(
    cfg: TrainConfig,
    open_session: Callable[[SessionConfig], SessionLike],
    *,
    resume: str | Path | None = None,
    init_from: str | Path | None = None,
    stage: str | None = None,
    runner_class: type[OnPolicyRunner] = OnPolicyRunner,
    servers: str = "",
    view: ViewTarget | None = None,
    evaluate: Callable[[OnPolicyRunner], dict[str, Any]] | None = None,
) -> list[dict[str, float]]:
    """Train ``cfg.runner.max_iterations`` (less a resumed run's) into ``cfg.runner.log_dir``.

    Args:
        cfg: The training config (``env.servers`` is the caller's: see ``open_session``).
        open_session: Opens the run's session from its config (e.g. ``open_session`` on a list
            of addresses, or a Ray pool's ``open_session``); the run closes it at the end.
        resume: A checkpoint to continue from (networks, optimisers, iteration).
        init_from: A checkpoint whose networks (only) start the run (staged training).
        stage: The command line of this run, kept in its checkpoints (model cards show it).
        runner_class: The runner (the Ray path's also logs server restarts).
        servers: Where the session runs, for the start line.
        view: Stream the run to a rerun live view (:mod:`unigait.live_view`); a resumed run
            continues the recording of its folder.
        evaluate: Judges the policy on a milestone (``recipe_runner.evaluate_milestone``'s
            record): every ``view.eval_every`` iterations, logged to the view.

    Returns:
        The logged scalars of each iteration.

    Raises:
        CheckpointMismatchError: ``resume`` or ``init_from`` holds other networks.
    """
    source = resume or init_from
    terrain_levels: list[int] = []
    mode_levels: list[int] = []
    if source:
        # A stage started from an upright policy (terrain after flat, say) keeps its threshold
        # too, rather than paying I_up from 1.0 rad again while the curriculum climbs back;
        # and its envs start on the terrain levels they had reached.
        checkpoint = torch.load(source, map_location="cpu", weights_only=False)
        cfg = resume_upright_curriculum(cfg, checkpoint)
        terrain_levels = resumed_terrain_levels(cfg, checkpoint)
        mode_levels = resumed_mode_levels(cfg, checkpoint)
    torch.manual_seed(cfg.runner.seed)
    if cfg.runner.torch_threads > 0:
        torch.set_num_threads(cfg.runner.torch_threads)
    log_dir = Path(cfg.runner.log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    (log_dir / "config.toml").write_text(cfg.to_toml())
    session_cfg = session_config(cfg, terrain_levels, mode_levels)
    if view is not None and view.envs > 0:  # the robot's drawing, to draw envs with
        session_cfg = dataclasses.replace(session_cfg, robot_drawing=True)
    env = TorchVecEnv(open_session(session_cfg), cfg.runner.device)
    if terrain_levels:
        mean = sum(terrain_levels) / len(terrain_levels)
        print(f"envs start on the terrain levels of {source} (mean {mean:.2f})")
        change = grid_change(checkpoint.get("terrain_columns", []), env.spec.terrain_columns)
        if change:
            print(change)
    runner: OnPolicyRunner | None = None
    try:
        runner = runner_class(env, cfg, log_dir)
        live = None
        if view is not None:
            live = LiveView(view, log_dir, f"train {log_dir.name}", env.spec.reward_terms)
            runner.sinks.append(live)
            runner.drawer = robot_drawer(live, env.spec, cfg.runner.seed)
        if resume:
            runner.load(resume)
            print(f"resumed from {resume} at iteration {runner.iteration}")
        elif init_from:
            runner.load_weights(init_from)
            print(f"networks initialised from {init_from}")
        if live is not None:
            started = f"resumed from {resume}" if resume else "started"
            live.event(runner.iteration, f"run {started} at iteration {runner.iteration}")
        if stage:
            runner.record_stage(stage)
        runner.provenance = {"git_commit": git_commit()}
        remaining = max(cfg.runner.max_iterations - runner.iteration, 0)
        print(
            f"training {env.num_envs} envs x {cfg.runner.num_steps_per_env} steps on "
            f"{servers or 'the session'} for {remaining} iterations; output in {log_dir}"
        )
        if live is None or view is None or evaluate is None or view.eval_every <= 0:
            return runner.learn(remaining)
        history: list[dict[str, float]] = []
        target = runner.iteration + remaining
        while runner.iteration < target:
            every = view.eval_every
            history += runner.learn(
                min(target - runner.iteration, every - runner.iteration % every)
            )
            if runner.iteration % every == 0:
                live.log_evaluation(evaluate(runner))
        return history
    finally:
        if runner is not None:
            runner.close()
        env.close()
