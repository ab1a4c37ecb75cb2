"""Learner configuration: dataclasses with defaults, TOML files and overrides.

Overrides look like ``section.key=value`` with the value parsed as TOML, e.g.
``ppo.learning_rate=3e-4``, ``env.servers=["a:1","b:2"]`` or, inside the task table,
``env.task.rewards.weights.biped_body_contact=-3.0``.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import tomllib
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from unigait.algorithms.estimator_learning import EstimatorConfig
from unigait.algorithms.ppo import PPOConfig
from unigait.client.types import SessionConfig


@dataclass(frozen=True)
class EnvConfig:
    """Where and what to simulate.

    Attributes:
        servers: Server addresses; several shard the batch. Empty: start a local server.
        server_bin: Binary for a local server (empty: ``$UNIGAIT_SERVER_BIN`` or the repo's build).
        num_envs: Envs in the batch (256: docs/src/decisions/0013-cpu-learner.md).
        seed: Session seed (shard i gets seed + i).
        task: The task config's overrides as a nested table (``{"rewards": {"weights":
            {"biped_body_contact": -3.0}}}``); the client sends it as TOML.
        terrain: ``"flat"``, ``"curriculum"`` or a pinned type.
        terrain_level: Level of a pinned type or the curriculum's highest starting level.
        terrain_columns: The curriculum grid's column types, in order (repeat a type to give it
            more columns); empty: the server's default 20, legged_gym's proportions.
    """

    servers: tuple[str, ...] = ()
    server_bin: str = ""
    num_envs: int = 256
    seed: int = 1
    task: dict[str, Any] = field(default_factory=dict)
    terrain: str = "flat"
    terrain_level: int = 0
    terrain_columns: tuple[str, ...] = ()

    def task_toml(self) -> str:
        """The task overrides as the TOML fragment the server's session config takes."""
        return toml_document(self.task) if self.task else ""


@dataclass(frozen=True)
class PolicyConfig:
    """Network shapes.

    Attributes:
        actor_hidden_dims: Actor MLP ((512, 256, 128)).
        critic_hidden_dims: Critic MLP ((512, 256, 128)).
        activation: ``"elu"``.
        init_noise_std: Initial action std (1.0).
        history_length: Observations in the history (3: o_t, o_{t-1}, o_{t-2}).
    """

    actor_hidden_dims: tuple[int, ...] = (512, 256, 128)
    critic_hidden_dims: tuple[int, ...] = (512, 256, 128)
    activation: str = "elu"
    init_noise_std: float = 1.0
    history_length: int = 3


@dataclass(frozen=True)
class RunnerConfig:
    """The training loop.

    Attributes:
        num_steps_per_env: Steps per env per iteration (24).
        max_iterations: Iterations of ``train`` (a resumed run counts from its checkpoint).
        save_interval: Checkpoint every this many iterations.
        plot_interval: Redraw the PNG every this many iterations.
        log_dir: Output directory (CSV, PNG, checkpoints, config).
        device: Torch device.
        torch_threads: Torch intra-op threads while rolling out (1; 0: torch's default). The
            server steps the envs on the same cores then; a second OpenMP thread only waits for
            a core the simulation holds.
        update_threads: Torch intra-op threads during the PPO and estimator updates (2; 0: as
            ``torch_threads``). The server is idle then, and the update is compute-bound. The
            CLI sets ``OMP_WAIT_POLICY=PASSIVE`` so that idle OpenMP threads sleep instead of
            spinning against the simulation.
        seed: Torch seed.
        quiet: Print one line per iteration instead of the full block.
        tensorboard: Also write the scalars as TensorBoard events in ``log_dir`` (the CSV's
            names, step = iteration).
    """

    num_steps_per_env: int = 24
    max_iterations: int = 500
    save_interval: int = 50
    plot_interval: int = 10
    log_dir: str = "runs/unigait"
    device: str = "cpu"
    torch_threads: int = 1
    update_threads: int = 2
    seed: int = 1
    quiet: bool = False
    tensorboard: bool = False


@dataclass(frozen=True)
class TrainConfig:
    """Everything ``python -m unigait train`` needs."""

    env: EnvConfig = field(default_factory=EnvConfig)
    policy: PolicyConfig = field(default_factory=PolicyConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    runner: RunnerConfig = field(default_factory=RunnerConfig)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Plain nested dict (tuples as lists)."""
        return {
            f.name: {
                k: list(v) if isinstance(v, tuple) else v
                for k, v in dataclasses.asdict(getattr(self, f.name)).items()
            }
            for f in dataclasses.fields(self)
        }

    def to_toml(self) -> str:
        """The config as TOML text (loadable with :func:`load_config`)."""
        return toml_document(self.to_dict())


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")


def _toml_tables(doc: dict[str, Any], prefix: str = "") -> list[str]:
    """``doc`` as TOML lines: its plain keys first, then each sub-table under its header."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    for k, v in doc.items():
        if isinstance(v, dict):
            name = f"{prefix}{k}"
            lines += ["", f"[{name}]", *_toml_tables(v, f"{name}.")]
    return lines


def toml_document(doc: dict[str, Any]) -> str:
    """``doc`` as a TOML document."""
    return "\n".join(_toml_tables(doc)).strip() + "\n"


def merged(base: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    """``base`` with ``update`` merged in, tables recursively (neither is changed)."""
    out = dict(base)
    for key, value in update.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merged(out[key], value)
        else:
            out[key] = value
    return out


def with_task_setting(task: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    """The task table with ``dotted`` (``table.sub.key``) set to ``value``."""
    *tables, key = dotted.split(".")
    update: dict[str, Any] = {key: value}
    for t in reversed(tables):
        update = {t: update}
    return merged(task, update)


def resume_upright_curriculum(cfg: TrainConfig, checkpoint: dict[str, Any]) -> TrainConfig:
    """``cfg`` with the upright curriculum starting where ``checkpoint``'s run left it.

    The server's curriculum starts every session at ``rewards.upright_curriculum.start``; a
    resumed run would otherwise fall back to it (1.0 rad) and spend iterations climbing back
    while I_up fires far below the pitch the policy had reached. Only when the run's task
    overrides turn the curriculum on and the checkpoint recorded a threshold.
    """
    threshold = checkpoint.get("upright_pitch")
    task = cfg.env.task
    curriculum = task.get("rewards", {}).get("upright_curriculum", {})
    if threshold is None or not curriculum.get("enabled", False):
        return cfg
    task = with_task_setting(task, "rewards.upright_curriculum.start", float(threshold))
    return dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, task=task))


#: The engine of a checkpoint or policy that does not say: every one written before learners
#: recorded the engine trained on rapier unless its task chose (decision record 0026).
ENGINE_BEFORE_RECORDING = "rapier"


def checkpoint_engine(checkpoint: Mapping[str, Any]) -> str:
    """The physics engine a checkpoint trained on.

    The one it recorded, else its task's choice, else rapier (the default before learners
    recorded it).
    """
    recorded = checkpoint.get("physics_engine")
    if recorded:
        return str(recorded)
    task = checkpoint.get("config", {}).get("env", {}).get("task", {})
    return str(task.get("physics", {}).get("engine") or ENGINE_BEFORE_RECORDING)


def checkpoint_engine_overrides(checkpoint: Mapping[str, Any]) -> str:
    """The task overrides that evaluate a checkpoint on the engine it trained on."""
    return f"physics.engine = {json.dumps(checkpoint_engine(checkpoint))}"


def same_task(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Whether two task tables train the same task.

    Equal, the upright curriculum's ``start`` aside (a resume sets it from the checkpoint).
    """

    def pruned(table: dict[str, Any]) -> dict[str, Any]:
        kept = {k: pruned(v) if isinstance(v, dict) else v for k, v in table.items()}
        return {k: v for k, v in kept.items() if v != {}}

    def core(task: dict[str, Any]) -> dict[str, Any]:
        task = copy.deepcopy(task)
        task.get("rewards", {}).get("upright_curriculum", {}).pop("start", None)
        return pruned(task)

    return core(a) == core(b)


def _coerce(section: type, key: str, value: Any) -> Any:
    hints = typing.get_type_hints(section)
    if key not in hints:
        known = [f.name for f in dataclasses.fields(section)]
        raise KeyError(f"unknown key {key!r} in [{section.__name__}]; known: {known}")
    hint = hints[key]
    if typing.get_origin(hint) is dict:
        if not isinstance(value, dict):
            raise TypeError(f"{section.__name__}.{key} must be a table, got {value!r}")
        return value
    if typing.get_origin(hint) is tuple:
        if not isinstance(value, list | tuple):
            value = [value]
        item = typing.get_args(hint)[0]
        if item in (int, float, str) and not all(
            isinstance(v, item) or (item is float and isinstance(v, int)) for v in value
        ):
            raise TypeError(f"{section.__name__}.{key} must hold {item.__name__}s, got {value!r}")
        return tuple(value)
    if hint is float and isinstance(value, int):
        return float(value)
    if hint is int and isinstance(value, float) and value.is_integer():
        return int(value)
    if hint in (int, float, str, bool) and not isinstance(value, hint):
        raise TypeError(f"{section.__name__}.{key} must be {hint.__name__}, got {value!r}")
    return value


def _task_entries(task: dict[str, Any], entries: dict[str, Any]) -> dict[str, Any]:
    """``entries`` of ``[env]`` with the task table merged into ``task``.

    ``task`` merges table by table (a stage adds a weight without restating the others);
    ``task.a.b = v`` (from ``--set env.task.a.b=v``) sets one value; ``task_overrides_toml``, the
    TOML-in-a-string form of checkpoints written before the task was a table, is read as one.
    """
    rest = {}
    for key, value in entries.items():
        if key == "task":
            if not isinstance(value, dict):
                raise TypeError(f"env.task must be a table, got {value!r}")
            task = merged(task, value)
        elif key.startswith("task."):
            task = with_task_setting(task, key.removeprefix("task."), value)
        elif key == "task_overrides_toml":
            task = merged(task, tomllib.loads(str(value)))
        else:
            rest[key] = value
    return {**rest, "task": task}


def apply(cfg: TrainConfig, values: dict[str, dict[str, Any]]) -> TrainConfig:
    """A copy of ``cfg`` with ``values[section][key]`` set (unknown names are errors).

    The task table (``env.task``) is merged into the current one rather than replaced.
    """
    sections = {f.name: f for f in dataclasses.fields(cfg)}
    changes: dict[str, Any] = {}
    for name, entries in values.items():
        if name not in sections:
            raise KeyError(f"unknown config section [{name}]; known: {sorted(sections)}")
        if not isinstance(entries, dict):
            raise TypeError(f"config section [{name}] must be a table, got {entries!r}")
        current = getattr(cfg, name)
        if name == "env":
            entries = _task_entries(current.task, entries)
        cls = type(current)
        updated = {k: _coerce(cls, k, v) for k, v in entries.items()}
        changes[name] = dataclasses.replace(current, **updated)
    return dataclasses.replace(cfg, **changes)


def parse_override(text: str) -> tuple[str, str, Any]:
    """``"ppo.learning_rate=3e-4"`` -> ``("ppo", "learning_rate", 3e-4)``.

    The value is parsed as a TOML value; a bare word that is not valid TOML is taken as a string.
    """
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise ValueError(f"override must look like section.key=value, got {text!r}")
    path, raw = text.split("=", 1)
    section, key = path.strip().split(".", 1)
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return section, key, value


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> TrainConfig:
    """Defaults, then the TOML file (if any), then the overrides, in that order."""
    cfg = TrainConfig()
    if path is not None:
        cfg = apply(cfg, tomllib.loads(Path(path).read_text()))
    grouped: dict[str, dict[str, Any]] = {}
    for text in overrides or []:
        section, key, value = parse_override(text)
        grouped.setdefault(section, {})[key] = value
    return apply(cfg, grouped)


def session_config(
    cfg: TrainConfig, terrain_levels: Sequence[int] = (), mode_levels: Sequence[int] = ()
) -> SessionConfig:
    """The session a training run opens (reward terms on: the logger needs them).

    ``terrain_levels``: each env's starting curriculum level (a resumed run's), or empty;
    ``mode_levels``: each env's starting (quad, biped) levels, two per env, or empty.
    """
    return SessionConfig(
        num_envs=cfg.env.num_envs,
        seed=cfg.env.seed,
        task_overrides_toml=cfg.env.task_toml(),
        terrain=cfg.env.terrain,
        terrain_level=cfg.env.terrain_level,
        terrain_levels=tuple(terrain_levels),
        terrain_mode_levels=tuple(mode_levels),
        terrain_columns=cfg.env.terrain_columns,
        reward_terms=True,
    )


def resumed_terrain_levels(cfg: TrainConfig, checkpoint: dict[str, Any]) -> list[int]:
    """The curriculum levels ``checkpoint``'s envs had reached, if this run can start there.

    Only for a curriculum run with as many envs as the checkpoint's: env i keeps its column
    (columns go by env index), so its level means the same tile again.
    """
    levels = [int(x) for x in checkpoint.get("terrain_levels", [])]
    if cfg.env.terrain != "curriculum" or len(levels) != cfg.env.num_envs:
        return []
    return levels


def resumed_mode_levels(cfg: TrainConfig, checkpoint: dict[str, Any]) -> list[int]:
    """Each env's (quad, biped) levels ``checkpoint``'s envs had reached, two per env.

    Empty unless :func:`resumed_terrain_levels` gives levels and the checkpoint holds both
    modes' (written by a run on a server that reports them; decision record 0036).
    """
    pairs = [int(x) for x in checkpoint.get("terrain_mode_levels", [])]
    if not resumed_terrain_levels(cfg, checkpoint) or len(pairs) != 2 * cfg.env.num_envs:
        return []
    return pairs
