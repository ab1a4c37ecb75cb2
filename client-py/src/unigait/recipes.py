"""Training recipes as data: stages in order, each a complete training config.

Why: docs/src/decisions/0021-recipes-as-data.md; how to use them: docs/src/recipes.md.

A recipe is a TOML file (home: ``assets/recipes/``; the package carries them)::

    description = "..."
    milestone = "M2"              # what `ship` judges its result by
    extends = "unified_flat"      # optional: start from that recipe's last stage's config
                                  # ("unified_flat:upright": from that stage's)

    [[stages]]
    name = "upright"
    start = "fresh"               # "fresh" | "previous" | a checkpoint path (from the repo root)
    start_best_of = 12            # optional, with "previous": the best of its last 12 checkpoints,
                                  # judged on this stage's milestone and check seeds
    start_rank = "pass_chance"    # optional: how they are ranked ("criteria", the default)
    carry = "weights"             # from a checkpoint: "weights" only, or "all" (optimisers too)
    [stages.stop]
    iterations = 6000             # the stage's length (its upper bound with a milestone)
    milestone = "M2"              # optional: stop early once met on the validation seed
    confirm_seed = 2001           # optional: ... and met again on this seed
    [stages.env]
    num_envs = 512
    [stages.task.rewards.weights] # the task config's overrides, as real tables
    biped_body_contact = -3.0
    [stages.ppo]
    entropy_coef = 0.0025

Each stage's config is the one before's (or the defaults, or ``extends``'s) with the stage's
tables merged in, so a stage states what it changes; ``--dry-run`` prints every stage resolved.
A stage that ran on code that no longer exists says so (``runs_at_head = false`` and
``ran_at``); such a recipe dry-runs but does not train.
"""

from __future__ import annotations

import dataclasses
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from unigait.assets import recipes_dir
from unigait.config import TrainConfig, apply, parse_override, toml_document

_RECIPE_KEYS = {"description", "milestone", "extends", "stages"}
#: How ``start_best_of``'s candidates can be ranked (``unigait.selection`` ranks them).
START_RANKS = ("criteria", "pass_chance")
_STAGE_KEYS = {
    "name",
    "note",
    "start",
    "start_best_of",
    "start_rank",
    "carry",
    "stop",
    "ran_at",
    "runs_at_head",
    "env",
    "task",
    "policy",
    "ppo",
    "estimator",
    "runner",
}
_STOP_KEYS = {
    "iterations",
    "milestone",
    "check_every",
    "validation_seed",
    "validation_envs",
    "confirm_seed",
}
#: Config sections a stage may set (``task`` goes into ``env.task``).
_SECTIONS = ("env", "policy", "ppo", "estimator", "runner")


class RecipeError(ValueError):
    """A recipe that cannot be read or resolved (the message names the file and the key)."""


@dataclass(frozen=True)
class StopRule:
    """When a stage ends.

    Attributes:
        iterations: Iterations of the stage (with ``milestone``: at most this many).
        milestone: Stop as soon as this milestone is met on the validation seed.
        check_every: Iterations between milestone checks.
        validation_seed: Seed of the milestone checks (never an evaluation seed).
        validation_envs: Envs per scenario of the milestone checks.
        confirm_seed: A second validation seed: a check met on ``validation_seed`` is judged
            again on this one, and the stage stops only if both are met. A milestone of few
            trials (Table VI's 20 a column) is met by one lucky draw far more often than by two
            independent ones.
    """

    iterations: int
    milestone: str | None = None
    check_every: int = 100
    validation_seed: int = 2000
    validation_envs: int = 64
    confirm_seed: int | None = None

    def check_seeds(self) -> list[int]:
        """The seeds a check is judged on, in order: the validation seed, then the confirm seed."""
        return [self.validation_seed] + ([] if self.confirm_seed is None else [self.confirm_seed])


@dataclass(frozen=True)
class Stage:
    """One resolved stage: how it starts, when it stops, and its whole training config.

    ``start_best_of`` (N > 0, with ``start = "previous"`` and a milestone): the stage starts from
    the best of the previous stage's last N checkpoints, judged on the stop rule's milestone and
    check seeds (ranked as ``ship --select-last`` ranks). Checkpoints 50 iterations apart can
    differ by more than a stage of training moves them, and a stage that settles at a low
    learning rate keeps whichever one it starts from. ``start_rank`` says how they are ranked:
    ``"criteria"`` (criteria met on each seed, the milestone's own sizes) or ``"pass_chance"``
    (every scenario on the stop rule's ``validation_envs``, by the chance of meeting the
    milestone on one unseen draw: :mod:`unigait.pass_chance`).
    """

    index: int
    name: str
    note: str
    start: str
    carry: str
    stop: StopRule
    config: TrainConfig
    ran_at: str | None
    runs_at_head: bool
    start_best_of: int = 0
    start_rank: str = "criteria"

    @property
    def dir_name(self) -> str:
        """The stage's folder in a recipe run's log directory (``01_upright``)."""
        return f"{self.index + 1:02d}_{self.name}"


@dataclass(frozen=True)
class Recipe:
    """A recipe with its stages resolved."""

    name: str
    path: Path
    text: str
    description: str
    milestone: str | None
    stages: tuple[Stage, ...]

    @property
    def runs_at_head(self) -> bool:
        """Whether every stage can train at this commit."""
        return all(s.runs_at_head for s in self.stages)


def recipe_path(name_or_path: str) -> Path:
    """The file of a packaged recipe ``name``, or ``name_or_path`` itself if it is a file.

    Raises:
        RecipeError: Neither (the message lists the packaged recipes).
    """
    path = Path(name_or_path)
    if path.suffix == ".toml" and path.is_file():
        return path
    packaged = recipes_dir() / f"{name_or_path}.toml"
    if packaged.is_file():
        return packaged
    raise RecipeError(f"unknown recipe {name_or_path!r}; packaged recipes: {recipe_names()}")


def recipe_names() -> list[str]:
    """The packaged recipes."""
    return sorted(p.stem for p in recipes_dir().glob("*.toml"))


def _unknown(table: Mapping[str, Any], known: set[str], where: str) -> None:
    extra = sorted(set(table) - known)
    if extra:
        raise RecipeError(f"{where}: unknown key(s) {extra}; known: {sorted(known)}")


def _stop_rule(raw: Any, where: str) -> StopRule:
    if not isinstance(raw, dict) or "iterations" not in raw:
        raise RecipeError(f"{where}: [stages.stop] must give iterations")
    _unknown(raw, _STOP_KEYS, f"{where} [stages.stop]")
    rule = StopRule(**raw)
    if rule.iterations < 1 or rule.check_every < 1:
        raise RecipeError(f"{where} [stages.stop]: iterations and check_every must be >= 1")
    if rule.confirm_seed is not None and rule.milestone is None:
        raise RecipeError(f"{where} [stages.stop]: confirm_seed confirms a milestone: give one")
    if rule.confirm_seed == rule.validation_seed:
        raise RecipeError(f"{where} [stages.stop]: confirm_seed must differ from validation_seed")
    return rule


def _stage_config(base: TrainConfig, raw: Mapping[str, Any], where: str) -> TrainConfig:
    """``base`` with the stage's tables merged in; unknown keys name the stage and the file."""
    values: dict[str, dict[str, Any]] = {
        s: dict(raw[s]) for s in _SECTIONS if isinstance(raw.get(s), dict)
    }
    for s in _SECTIONS:
        if s in raw and not isinstance(raw[s], dict):
            raise RecipeError(f"{where}: [stages.{s}] must be a table")
    if "task" in raw:
        if not isinstance(raw["task"], dict):
            raise RecipeError(f"{where}: [stages.task] must be a table")
        if "task" in values.get("env", {}) or "task_overrides_toml" in values.get("env", {}):
            raise RecipeError(f"{where}: give the task as [stages.task], not inside [stages.env]")
        values.setdefault("env", {})["task"] = raw["task"]
    elif "task_overrides_toml" in values.get("env", {}):
        raise RecipeError(f"{where}: give the task overrides as [stages.task] tables, not a string")
    try:
        return apply(base, values)
    except (KeyError, TypeError) as err:
        message = err.args[0] if err.args else str(err)
        raise RecipeError(f"{where}: {message}") from err


def _overridden(cfg: TrainConfig, sets: Sequence[str]) -> TrainConfig:
    grouped: dict[str, dict[str, Any]] = {}
    for text in sets:
        section, key, value = parse_override(text)
        grouped.setdefault(section, {})[key] = value
    return apply(cfg, grouped)


def load_recipe(name_or_path: str, sets: Sequence[str] = (), _seen: tuple[str, ...] = ()) -> Recipe:
    """Read and resolve a recipe; ``sets`` (``section.key=value``) apply on top of every stage.

    Raises:
        RecipeError: An unreadable file, an unknown key or a bad value (named with the file).
    """
    path = recipe_path(name_or_path)
    text = path.read_text()
    where = str(path)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise RecipeError(f"{where}: {err}") from err
    _unknown(doc, _RECIPE_KEYS, where)
    stages_raw = doc.get("stages")
    if not isinstance(stages_raw, list) or not stages_raw:
        raise RecipeError(f"{where}: a recipe needs at least one [[stages]]")
    cfg = TrainConfig()
    if "extends" in doc:
        # "recipe" takes its last stage's config, "recipe:stage" that stage's.
        parent, _, parent_stage = str(doc["extends"]).partition(":")
        if parent in _seen or parent == path.stem:
            raise RecipeError(f"{where}: extends {parent!r} in a loop")
        parents = load_recipe(parent, (), (*_seen, path.stem)).stages
        chosen = [s for s in parents if s.name == parent_stage] if parent_stage else parents[-1:]
        if not chosen:
            raise RecipeError(f"{where}: extends {doc['extends']!r}: {parent} has no such stage")
        cfg = chosen[0].config
    stages: list[Stage] = []
    names: set[str] = set()
    for i, raw in enumerate(stages_raw):
        here = f"{where} stage {i + 1}"
        if not isinstance(raw, dict):
            raise RecipeError(f"{here}: a stage must be a table")
        _unknown(raw, _STAGE_KEYS, here)
        name = str(raw.get("name", ""))
        if not name or not name.replace("_", "").isalnum() or name in names:
            raise RecipeError(f"{here}: needs a unique name of letters, digits and _")
        names.add(name)
        here = f"{where} stage {i + 1} ({name})"
        start = str(raw.get("start", "fresh" if i == 0 else "previous"))
        if start == "previous" and i == 0:
            raise RecipeError(f"{here}: the first stage has no previous stage to start from")
        carry = str(raw.get("carry", "weights"))
        if carry not in ("weights", "all"):
            raise RecipeError(f"{here}: carry must be 'weights' or 'all', got {carry!r}")
        stop = _stop_rule(raw.get("stop"), here)
        best_of = raw.get("start_best_of", 0)
        if not isinstance(best_of, int) or isinstance(best_of, bool) or best_of < 0:
            raise RecipeError(f"{here}: start_best_of must be a count of checkpoints (>= 0)")
        if best_of and (start != "previous" or stop.milestone is None):
            raise RecipeError(
                f"{here}: start_best_of chooses among the previous stage's checkpoints by the "
                'stage\'s milestone: give start = "previous" and [stages.stop] milestone'
            )
        start_rank = raw.get("start_rank", "criteria")
        if start_rank not in START_RANKS:
            raise RecipeError(
                f"{here}: start_rank must be one of {', '.join(START_RANKS)}, got {start_rank!r}"
            )
        if "start_rank" in raw and not best_of:
            raise RecipeError(f"{here}: start_rank ranks start_best_of's candidates: give both")
        cfg = _stage_config(cfg, raw, here)
        try:
            resolved = _overridden(cfg, sets)
        except (KeyError, TypeError, ValueError) as err:
            raise RecipeError(f"--set: {err.args[0] if err.args else err}") from err
        stages.append(
            Stage(
                index=i,
                name=name,
                note=str(raw.get("note", "")),
                start=start,
                carry=carry,
                stop=stop,
                config=resolved,
                ran_at=raw.get("ran_at"),
                runs_at_head=bool(raw.get("runs_at_head", True)),
                start_best_of=best_of,
                start_rank=start_rank,
            )
        )
    milestone = doc.get("milestone")
    return Recipe(
        name=path.stem,
        path=path,
        text=text,
        description=str(doc.get("description", "")),
        milestone=None if milestone is None else str(milestone),
        stages=tuple(stages),
    )


def _diff(before: dict[str, Any], after: dict[str, Any], prefix: str = "") -> list[str]:
    """``section.key = value`` lines for what ``after`` changes in ``before``."""
    lines = []
    for key, value in after.items():
        old = before.get(key)
        if isinstance(value, dict):
            lines += _diff(old if isinstance(old, dict) else {}, value, f"{prefix}{key}.")
        elif old != value:
            lines.append(f"{prefix}{key} = {value!r}")
    return lines


#: Runner keys a recipe decides itself (the stage's folder, its stop rule): not shown.
_RECIPE_DECIDES = ("log_dir", "max_iterations")


def _shown(cfg: TrainConfig) -> dict[str, Any]:
    doc = cfg.to_dict()
    doc["runner"] = {k: v for k, v in doc["runner"].items() if k not in _RECIPE_DECIDES}
    return doc


def describe(recipe: Recipe) -> str:
    """The resolved stages as text (``train --recipe NAME --dry-run``)."""
    lines = [f"recipe {recipe.name} ({recipe.path})"]
    if recipe.description:
        lines.append(f"  {recipe.description}")
    if recipe.milestone:
        lines.append(f"  judged by milestone {recipe.milestone}")
    if not recipe.runs_at_head:
        lines.append("  NOT runnable at this commit: some stages ran on code that no longer exists")
    before = _shown(TrainConfig())
    for stage in recipe.stages:
        after = _shown(stage.config)
        stop = f"{stage.stop.iterations} iterations"
        if stage.stop.milestone:
            seeds = f"seed {stage.stop.validation_seed}"
            if stage.stop.confirm_seed is not None:
                seeds = "seeds " + " and ".join(str(seed) for seed in stage.stop.check_seeds())
            stop = (
                f"milestone {stage.stop.milestone} met on {seeds} "
                f"(checked every {stage.stop.check_every}), at most {stop}"
            )
        start = stage.start if stage.start in ("fresh", "previous") else f"from {stage.start}"
        if stage.start_best_of:
            checked = " and ".join(str(seed) for seed in stage.stop.check_seeds())
            by = (
                f"by the chance of meeting {stage.stop.milestone} on one draw, "
                f"{stage.stop.validation_envs} envs a scenario"
                if stage.start_rank == "pass_chance"
                else f"on {stage.stop.milestone}"
            )
            start = (
                f"previous: the best of its last {stage.start_best_of} checkpoints {by}, "
                f"seeds {checked}"
            )
        lines += [
            "",
            f"stage {stage.index + 1}: {stage.name} [{start}, carry {stage.carry}; stop: {stop}]",
        ]
        if stage.note:
            lines.append(f"  note: {stage.note}")
        if not stage.runs_at_head:
            lines.append(f"  ran at commit {stage.ran_at}; does not run at this commit")
        changes = _diff(before, after)
        lines += [f"  {c}" for c in changes] or ["  (no change)"]
        before = after
    lines += ["", "last stage, resolved:", toml_document(_shown(recipe.stages[-1].config))]
    return "\n".join(lines)


def stage_config(stage: Stage, log_dir: Path) -> TrainConfig:
    """The stage's config writing into ``log_dir``."""
    runner = dataclasses.replace(stage.config.runner, log_dir=str(log_dir))
    return dataclasses.replace(stage.config, runner=runner)
