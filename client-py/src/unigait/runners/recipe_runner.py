"""Run a recipe's stages unattended, and carry on where an interrupted run stopped.

A recipe run's log directory holds the recipe as it started (``recipe.toml``, ``run.json``) and
one folder per stage (``01_upright/``: the stage's ``progress.csv``, checkpoints and, once it has
ended, ``done.json``). Running the same command again skips the ended stages, resumes the stage
in progress from its latest checkpoint and goes on.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch

from unigait.client import Client, ConnectionOptions, open_session
from unigait.config import (
    TrainConfig,
    resume_upright_curriculum,
    resumed_mode_levels,
    resumed_terrain_levels,
    session_config,
)
from unigait.env import TorchVecEnv
from unigait.env.terrain_stats import grid_change
from unigait.export import export_onnx
from unigait.live_view import LiveView, ViewTarget, robot_drawer
from unigait.milestones import milestone as load_milestone
from unigait.provenance import git_commit
from unigait.recipes import Recipe, Stage, stage_config
from unigait.runners.on_policy_runner import OnPolicyRunner
from unigait.selection import recent_checkpoints, select_checkpoint

RECIPE_FILE = "recipe.toml"
RUN_FILE = "run.json"
DONE_FILE = "done.json"
STAGE_FILE = "stage.json"


class RecipeRunError(RuntimeError):
    """A recipe run that cannot start or go on (the message says what to do)."""


def _read_json(path: Path) -> dict[str, Any]:
    return dict(json.loads(path.read_text()))


def _write_json(path: Path, value: dict[str, Any]) -> None:
    partial = path.with_name(f".{path.name}.partial")
    partial.write_text(json.dumps(value, indent=2) + "\n")
    partial.replace(path)


def prepare_log_dir(
    recipe: Recipe, sets: Sequence[str], log_dir: Path, overwrite: bool, adopt: bool
) -> None:
    """Start ``log_dir`` for ``recipe``, or check that it holds a run of the same recipe.

    Raises:
        RecipeRunError: The folder holds something else, or the recipe changed since the run
            started (``adopt`` goes on with the new text; ``overwrite`` starts afresh).
    """
    if overwrite and log_dir.exists():
        shutil.rmtree(log_dir)
    stored = log_dir / RECIPE_FILE
    if stored.exists():
        run = _read_json(log_dir / RUN_FILE) if (log_dir / RUN_FILE).exists() else {}
        same = stored.read_text() == recipe.text and list(run.get("sets", [])) == list(sets)
        if not same and not adopt:
            raise RecipeRunError(
                f"{log_dir} holds a run of another recipe text or --set list than this one "
                f"({run.get('recipe', '?')}): give --adopt-recipe to go on with this one (ended "
                "stages are kept), --overwrite to start afresh, or another --log-dir"
            )
    elif log_dir.exists() and any(log_dir.iterdir()):
        raise RecipeRunError(
            f"{log_dir} is not empty and holds no recipe run: give another --log-dir or --overwrite"
        )
    log_dir.mkdir(parents=True, exist_ok=True)
    stored.write_text(recipe.text)
    _write_json(
        log_dir / RUN_FILE,
        {"recipe": recipe.name, "source": str(recipe.path), "sets": list(sets)},
    )


def _log_check(
    stage: Stage, stage_dir: Path, record: dict[str, Any], log: Callable[[str], None]
) -> None:
    """Append a milestone check to the stage's ``validation.jsonl`` and log it."""
    with (stage_dir / "validation.jsonl").open("a") as f:
        f.write(json.dumps(record) + "\n")
    log(
        f"stage {stage.dir_name}: iteration {record['iteration']}: {record['milestone']} "
        f"{record['criteria_met']}/{record['criteria']} on seed {record['seed']}"
        + "".join(f"\n  unmet: {u}" for u in record["unmet"])
    )


def _evaluate_milestone(
    runner: OnPolicyRunner, stage: Stage, address: str, connection: ConnectionOptions
) -> tuple[bool, dict[str, Any]]:
    """Export the current policy and judge it on the stage's milestone and validation seed."""
    rule = stage.stop
    assert rule.milestone is not None
    return evaluate_milestone(
        runner, rule.milestone, rule.validation_envs, rule.validation_seed, address, connection
    )


def evaluate_milestone(
    runner: OnPolicyRunner,
    name: str,
    envs: int,
    seed: int,
    address: str,
    connection: ConnectionOptions,
) -> tuple[bool, dict[str, Any]]:
    """Export the current policy and judge it on milestone ``name`` (its scenarios on ``seed``).

    The recipes' milestone checks and the live view's evaluations both come from here, so the
    curve a user watches is the one a stage stops on. The scenarios run on the physics engine
    the runner trains on (the one its session reports); they set the rest of the task.

    Returns:
        Whether every criterion is met, and the record (``validation.jsonl``'s row).
    """
    target = load_milestone(name)
    evals: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        onnx_path = Path(tmp) / "policy.onnx"
        export_onnx(
            runner.policy(),
            onnx_path,
            runner.dims["history_length"],
            runner.dims["obs_dim"],
            physics_engine=runner.physics_engine,
        )
        onnx = onnx_path.read_bytes()
        with Client(address, **connection) as client:
            for scenario in target.scenarios:
                result = client.evaluate(
                    onnx,
                    scenario,
                    num_envs=target.envs_for(scenario, envs),
                    seed=seed,
                    task_overrides_toml=f"physics.engine = {json.dumps(runner.physics_engine)}",
                )
                evals[scenario] = dict(result.metrics)
    met, margin = target.score(evals)
    return target.met(evals), {
        "iteration": runner.iteration,
        "milestone": target.name,
        "criteria_met": met,
        "criteria": target.criteria(),
        "margin": margin,
        "unmet": target.unmet(evals),
        "seed": seed,
        "evals": evals,
    }


def _start_checkpoint(stage: Stage, previous_final: Path | None) -> Path | None:
    if stage.start == "fresh":
        return None
    if stage.start == "previous":
        assert previous_final is not None
        return previous_final
    path = Path(stage.start)
    if not path.is_file():
        raise RecipeRunError(f"stage {stage.name} starts from {path}, which does not exist")
    return path


def _best_start(
    stage: Stage,
    previous_final: Path,
    address: str,
    connection: ConnectionOptions,
    log: Callable[[str], None],
) -> tuple[Path, dict[str, Any]]:
    """The best of the previous stage's last ``start_best_of`` checkpoints, and how it was chosen.

    Each is judged on the stage's milestone on every check seed; a run folder that kept only
    the previous stage's final checkpoint (a clone of a committed run) starts from that.
    """
    rule = stage.stop
    assert rule.milestone is not None
    folder = previous_final.parent
    if not recent_checkpoints(folder, stage.start_best_of):
        log(f"stage {stage.dir_name}: no numbered checkpoints in {folder}; starts from its final")
        return previous_final, {"candidates": [], "chosen": str(previous_final)}
    target = load_milestone(rule.milestone)
    seeds = rule.check_seeds()
    ranked = select_checkpoint(
        folder,
        target,
        address,
        stage.start_best_of,
        seeds,
        rule.validation_envs,
        connection,
        by=stage.start_rank,
        judged_envs=rule.validation_envs,
    )
    chosen = ranked[0]
    scores = ", ".join(
        f"{c.iteration}: {c.met_per_seed(target.criteria())}"
        + ("" if c.chance is None else f" (chance {c.chance:.2f})")
        for c in sorted(ranked, key=lambda c: c.iteration)
    )
    log(
        f"stage {stage.dir_name}: starts from {chosen.path.name}, the best of {len(ranked)} on "
        f"{target.name}{' by the pass chance' if stage.start_rank == 'pass_chance' else ''}, "
        f"seeds {' and '.join(map(str, seeds))} ({scores})"
    )
    record = {
        "milestone": target.name,
        "seeds": seeds,
        "rank": stage.start_rank,
        "candidates": [
            {
                "iteration": c.iteration,
                "scores": [{"seed": s.seed, "met": s.met, "margin": s.margin} for s in c.scores],
                **({} if c.chance is None else {"chance": c.chance}),
            }
            for c in sorted(ranked, key=lambda c: c.iteration)
        ],
        "chosen": str(chosen.path),
    }
    return chosen.path, record


def run_stage(
    recipe: Recipe,
    stage: Stage,
    stage_dir: Path,
    previous_final: Path | None,
    addresses: Sequence[str],
    connection: ConnectionOptions,
    log: Callable[[str], None],
    view: LiveView | None = None,
    view_offset: int = 0,
    tensorboard: bool = False,
) -> Path:
    """Train one stage to its stop rule (resuming its own latest checkpoint if it has one).

    Args:
        recipe: The recipe.
        stage: The stage.
        stage_dir: Its folder.
        previous_final: The previous stage's final checkpoint (None for the first).
        addresses: The servers.
        connection: How to reach them.
        log: Progress lines.
        view: The recipe's live view, if any (one recording for every stage).
        view_offset: Iterations of the recipe's earlier stages: the view's timeline counts the
            recipe's iterations, as a stage's own may start again from 0.
        tensorboard: Also write TensorBoard events into the stage's folder.

    Returns:
        The stage's final checkpoint.
    """
    latest = stage_dir / "model_latest.pt"
    resuming = latest.exists() and (stage_dir / STAGE_FILE).exists()
    if not resuming:
        # Killed before its first checkpoint: nothing to resume, and its log rows would be
        # counted twice.
        shutil.rmtree(stage_dir, ignore_errors=True)
    stage_dir.mkdir(parents=True, exist_ok=True)
    source = latest if resuming else _start_checkpoint(stage, previous_final)
    start_selection: dict[str, Any] | None = None
    if not resuming and stage.start_best_of and previous_final is not None:
        source, start_selection = _best_start(stage, previous_final, addresses[0], connection, log)
    cfg: TrainConfig = stage_config(stage, stage_dir)
    if tensorboard:
        cfg = dataclasses.replace(cfg, runner=dataclasses.replace(cfg.runner, tensorboard=True))
    terrain_levels: list[int] = []
    mode_levels: list[int] = []
    if source is not None:
        checkpoint = torch.load(source, map_location="cpu", weights_only=False)
        cfg = resume_upright_curriculum(cfg, checkpoint)
        terrain_levels = resumed_terrain_levels(cfg, checkpoint)
        mode_levels = resumed_mode_levels(cfg, checkpoint)
    torch.manual_seed(cfg.runner.seed)
    if cfg.runner.torch_threads > 0:
        torch.set_num_threads(cfg.runner.torch_threads)
    session_cfg = session_config(cfg, terrain_levels, mode_levels)
    if view is not None and view.target.envs > 0:  # the robot's drawing, to draw envs with
        session_cfg = dataclasses.replace(session_cfg, robot_drawing=True)
    session = open_session(list(addresses), session_cfg, **connection)
    if terrain_levels:
        mean = sum(terrain_levels) / len(terrain_levels)
        log(
            f"stage {stage.dir_name}: envs start on the terrain levels of {source} "
            f"(mean {mean:.2f})"
        )
        change = grid_change(checkpoint.get("terrain_columns", []), session.spec.terrain_columns)
        if change:
            log(f"stage {stage.dir_name}: {change}")
    env = TorchVecEnv(session, cfg.runner.device)
    runner: OnPolicyRunner | None = None
    try:
        runner = OnPolicyRunner(env, cfg, stage_dir)
        if resuming:
            runner.load(latest)
            start_iteration = int(_read_json(stage_dir / STAGE_FILE)["start_iteration"])
            log(f"stage {stage.dir_name}: resumed at iteration {runner.iteration}")
        else:
            if source is not None and stage.carry == "all":
                runner.load(source)
            elif source is not None:
                runner.load_weights(source)
            start_iteration = runner.iteration
            _write_json(
                stage_dir / STAGE_FILE,
                {
                    "start_iteration": start_iteration,
                    "started_from": None if source is None else str(source),
                    "carry": stage.carry,
                }
                | ({} if start_selection is None else {"start_selection": start_selection}),
            )
        count = len(recipe.stages)
        line = f"recipe {recipe.name}, stage {stage.index + 1} of {count}: {stage.name}"
        if not runner.stages or runner.stages[-1] != line:
            runner.stages.append(line)
        runner.provenance = {
            "recipe": recipe.name,
            "recipe_text": recipe.text,
            "stage": stage.index + 1,
            "stage_name": stage.name,
            "git_commit": git_commit(),
        }
        target = start_iteration + stage.stop.iterations
        rule = stage.stop
        if view is not None:
            view.offset = view_offset - start_iteration
            view.reward_terms = list(env.spec.reward_terms)
            runner.sinks.append(view)
            runner.drawer = robot_drawer(view, env.spec, cfg.runner.seed)
            what = "resumed" if resuming else "starts"
            view.event(
                runner.iteration,
                f"stage {stage.index + 1} of {len(recipe.stages)} ({stage.name}) {what} at "
                f"its iteration {runner.iteration}",
            )
        log(
            f"stage {stage.dir_name}: {env.num_envs} envs, iterations "
            f"{runner.iteration + 1}-{target}"
            + (f", stops early on {rule.milestone}" if rule.milestone else "")
        )
        view_every = view.target.eval_every if view is not None else 0
        while runner.iteration < target:
            chunk = target - runner.iteration
            if rule.milestone:
                done_in_stage = runner.iteration - start_iteration
                chunk = min(chunk, rule.check_every - done_in_stage % rule.check_every)
            if view_every:
                chunk = min(chunk, view_every - runner.iteration % view_every)
            runner.learn(chunk)
            record: dict[str, Any] | None = None
            met = False
            if rule.milestone and (runner.iteration - start_iteration) % rule.check_every == 0:
                met, record = _evaluate_milestone(runner, stage, addresses[0], connection)
                _log_check(stage, stage_dir, record, log)
                if met and rule.confirm_seed is not None:
                    met, confirmed = evaluate_milestone(
                        runner,
                        rule.milestone,
                        rule.validation_envs,
                        rule.confirm_seed,
                        addresses[0],
                        connection,
                    )
                    _log_check(stage, stage_dir, confirmed, log)
            own = view is not None and view_every and runner.iteration % view_every == 0
            if view is not None and own and record is None:  # the view's own evaluation
                t = view.target
                name = rule.milestone or t.eval_milestone
                _, record = evaluate_milestone(
                    runner, name, t.eval_envs, t.eval_seed, addresses[0], connection
                )
            if view is not None and record is not None:
                view.log_evaluation(record)
            if met:
                break
        final = stage_dir / f"model_{runner.iteration}.pt"
        if not final.exists():  # nothing left to train: the resumed checkpoint is the last one
            runner.save(final)
        reason = "iterations"
        if runner.iteration < target:
            reason = f"milestone {rule.milestone} met on seed {rule.validation_seed}"
            if rule.confirm_seed is not None:
                reason += f" and {rule.confirm_seed}"
        _write_json(
            stage_dir / DONE_FILE,
            {
                "final_checkpoint": final.name,
                "iteration": runner.iteration,
                "stage_iterations": runner.iteration - start_iteration,
                "env_steps": runner.total_env_steps,
                "reason": reason,
            },
        )
        return final
    finally:
        if runner is not None:
            if view is not None and view in runner.sinks:
                runner.sinks.remove(view)  # the recipe's: it outlives the stage
            runner.close()
        env.close()


def run_recipe(
    recipe: Recipe,
    sets: Sequence[str],
    log_dir: Path,
    addresses: Sequence[str],
    connection: ConnectionOptions,
    *,
    overwrite: bool = False,
    adopt: bool = False,
    log: Callable[[str], None] = lambda text: print(text, file=sys.stderr),
    view: ViewTarget | None = None,
    tensorboard: bool = False,
) -> Path:
    """Every stage of ``recipe`` in order, skipping those a previous call ended.

    Returns:
        The last stage's final checkpoint.

    Raises:
        RecipeRunError: The recipe does not run at this commit, or the log directory holds
            something else.
        ViewError: The live view cannot be set up.
    """
    if not recipe.runs_at_head:
        stale = [s.name for s in recipe.stages if not s.runs_at_head]
        raise RecipeRunError(
            f"recipe {recipe.name} records stages that ran on code that no longer exists "
            f"({', '.join(stale)}): it documents history; train a recipe that runs at this commit"
        )
    prepare_log_dir(recipe, sets, log_dir, overwrite, adopt)
    live = None if view is None else LiveView(view, log_dir, f"recipe {recipe.name}")
    try:
        final = _run_stages(recipe, log_dir, addresses, connection, log, live, tensorboard)
    finally:
        if live is not None:
            live.close()
    latest = log_dir / "final.pt"
    shutil.copyfile(final, latest.with_name(".final.pt.partial"))
    latest.with_name(".final.pt.partial").replace(latest)
    log(f"recipe {recipe.name} done: {latest} (from {final})")
    return latest


def _run_stages(
    recipe: Recipe,
    log_dir: Path,
    addresses: Sequence[str],
    connection: ConnectionOptions,
    log: Callable[[str], None],
    view: LiveView | None,
    tensorboard: bool,
) -> Path:
    """Each stage not ended yet, in order; the last stage's final checkpoint."""
    final: Path | None = None
    done_iterations = 0  # the earlier stages' iterations: where the view's timeline is
    for stage in recipe.stages:
        stage_dir = log_dir / stage.dir_name
        done = stage_dir / DONE_FILE
        if done.exists():
            done_iterations += int(_read_json(done).get("stage_iterations", 0))
            final = stage_dir / str(_read_json(done)["final_checkpoint"])
            if not final.exists():
                # A run folder kept in git holds only the latest checkpoint, which an ended
                # stage's final one is (runner.save writes both).
                final = stage_dir / "model_latest.pt"
            log(f"stage {stage.dir_name}: ended before ({final})")
            continue
        final = run_stage(
            recipe,
            stage,
            stage_dir,
            final,
            addresses,
            connection,
            log,
            view=view,
            view_offset=done_iterations,
            tensorboard=tensorboard,
        )
        done_iterations += int(_read_json(stage_dir / DONE_FILE)["stage_iterations"])
    assert final is not None
    return final
