"""Plain data types exchanged with the server: session config, server info, step results."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from unigait.client.proto import pb
from unigait.client.spec import Spec
from unigait.client.tensors import decode


@dataclass(frozen=True)
class SessionConfig:
    r"""Configuration of a new session (a batch of envs).

    Attributes:
        num_envs: Number of envs (1 .. the server's limit).
        seed: Seed of every random draw.
        task_overrides_toml: TOML fragment overriding the task config, e.g.
            ``"[modes]\\nbiped_probability = 0.0"``.
        terrain: ``"flat"``, ``"curriculum"`` or a pinned type (``"stairs_up"``, ...).
        terrain_level: Level of a pinned type, or the highest starting level for the curriculum.
        terrain_levels: The curriculum only: each env's starting level (one per env), e.g. the
            levels a resumed run had reached; empty: drawn from ``0..=terrain_level``.
        terrain_mode_levels: The curriculum only: each env's starting (quad, biped) levels, two
            per env, e.g. a resumed run's ``StepResult.mode_levels`` (used when the task keeps a
            level per mode); empty: both modes start on the env's level.
        terrain_columns: The curriculum only: the grid's column types, in order (repeat a type
            to give it more columns); empty: the server's default 20 (``Spec.terrain_columns``).
        autoreset: ``"same_step"`` (default) or ``"disabled"``.
        reward_terms: Return the per-term rewards with every step.
        robot_drawing: Send the robot's drawing with the spec (``Spec.robot_drawing_rrd``), for
            a live view that asks steps for envs' body poses (``draw_envs``).
    """

    num_envs: int
    seed: int = 0
    task_overrides_toml: str = ""
    terrain: str = "flat"
    terrain_level: int = 0
    terrain_levels: tuple[int, ...] = ()
    terrain_mode_levels: tuple[int, ...] = ()
    terrain_columns: tuple[str, ...] = ()
    autoreset: str = "same_step"
    reward_terms: bool = True
    robot_drawing: bool = False

    def to_proto(self) -> Any:
        """The ``unigait.v1.SessionConfig`` message."""
        modes = {
            "same_step": pb.AUTORESET_MODE_SAME_STEP,
            "disabled": pb.AUTORESET_MODE_DISABLED,
        }
        if self.autoreset not in modes:
            raise ValueError(f"autoreset must be one of {sorted(modes)}, got {self.autoreset!r}")
        return pb.SessionConfig(
            num_envs=self.num_envs,
            seed=self.seed,
            task_overrides_toml=self.task_overrides_toml,
            terrain=pb.TerrainConfig(
                kind=self.terrain,
                level=self.terrain_level,
                initial_levels=self.terrain_levels,
                initial_mode_levels=self.terrain_mode_levels,
                columns=self.terrain_columns,
            ),
            autoreset=modes[self.autoreset],
            reward_terms=self.reward_terms,
            robot_drawing=self.robot_drawing,
        )


@dataclass(frozen=True)
class ServerInfo:
    """What ``GetServerInfo`` reports."""

    protocol_version: str
    server_version: str
    max_envs_per_session: int
    max_sessions: int
    active_sessions: int
    threads: int
    max_message_bytes: int

    @classmethod
    def from_proto(cls, msg: Any) -> ServerInfo:
        """Build from a ``unigait.v1.ServerInfo``."""
        return cls(
            protocol_version=msg.protocol_version,
            server_version=msg.server_version,
            max_envs_per_session=int(msg.max_envs_per_session),
            max_sessions=int(msg.max_sessions),
            active_sessions=int(msg.active_sessions),
            threads=int(msg.threads),
            max_message_bytes=int(msg.max_message_bytes),
        )


@dataclass
class StepResult:
    """One batched step (or reset) of N envs, as numpy arrays (read-only views of the reply).

    Attributes:
        obs: f32 [N, 53] o_t, after autoreset (a reset env shows its new first observation).
        labels: f32 [N, 14] e_t estimator labels.
        privileged: f32 [N, 10] s_t domain-randomisation values.
        reward: f32 [N] total reward.
        reward_terms: f32 [N, T] weighted reward per term (T = len(spec.reward_terms)), or None
            when not asked for.
        terminated: bool [N], episode ended by a trunk contact (or a physics blow-up).
        truncated: bool [N], episode ended by time-out.
        final_env_ids: int64 [K] envs that ended this step.
        final_obs: f32 [K, 53] last observation of each ended episode (rows follow final_env_ids).
        final_labels: f32 [K, 14] last labels of each ended episode.
        final_privileged: f32 [K, 10] privileged values of each ended episode.
        final_episode_length: int64 [K] length in steps of each ended episode.
        mode: u8 [N] task mode for the next action (1 biped, 2 quad).
        terrain_level: int64 [N] terrain difficulty level.
        step_count: Steps taken by the session so far (the largest over shards).
        nonfinite_resets: Envs reset after a physics blow-up in this step.
        head_contact: bool [N], the head touched the terrain this step (reported only: it
            neither terminates nor costs reward).
        upright_pitch: Pitch (rad) above which the upright indicator fires from the next step
            on: the task's ``rewards.upright_pitch`` or where its upright curriculum has got
            (the mean over shards, each of which runs its own); None from older servers.
        mode_levels: int64 [N, 2] each env's own (quad, biped) levels: both ``terrain_level``
            unless the task keeps a level per mode; None from older servers.
        body_poses: f32 [K, B, 7], each body's world pose (x, y, z, qx, qy, qz, qw) of the K
            envs the step named in ``draw_envs`` (in that order; bodies as
            ``Spec.body_names``); None when it named none.
    """

    obs: np.ndarray
    labels: np.ndarray
    privileged: np.ndarray
    reward: np.ndarray
    reward_terms: np.ndarray | None
    terminated: np.ndarray
    truncated: np.ndarray
    final_env_ids: np.ndarray
    final_obs: np.ndarray
    final_labels: np.ndarray
    final_privileged: np.ndarray
    final_episode_length: np.ndarray
    mode: np.ndarray
    terrain_level: np.ndarray
    step_count: int = 0
    nonfinite_resets: int = 0
    head_contact: np.ndarray | None = None
    upright_pitch: float | None = None
    body_poses: np.ndarray | None = None
    mode_levels: np.ndarray | None = None

    @property
    def num_envs(self) -> int:
        """N."""
        return int(self.obs.shape[0])

    @property
    def dones(self) -> np.ndarray:
        """bool [N]: terminated or truncated."""
        return self.terminated | self.truncated

    @classmethod
    def from_proto(cls, msg: Any, spec: Spec) -> StepResult:
        """Decode a ``unigait.v1.StepResult`` (zero-copy where the dtype allows).

        Args:
            msg: The reply.
            spec: The session's spec (row shapes of absent tensors).
        """
        n = spec.num_envs
        obs = decode(msg.obs, (spec.obs_dim,))
        n = obs.shape[0] if obs.shape[0] else n

        def flag(t: Any) -> np.ndarray:
            a = decode(t, (), "u1")
            return a != 0 if a.size else np.zeros(n, dtype=bool)

        reward = decode(msg.reward, ())
        terms = decode(msg.reward_terms, (len(spec.reward_terms),))
        mode = decode(msg.mode, (), "u1")
        level = decode(msg.terrain_level, (), "<u4")
        mode_levels = decode(msg.mode_levels, (2,), "<u4")
        return cls(
            obs=obs,
            labels=decode(msg.labels, (spec.label_dim,)),
            privileged=decode(msg.privileged, (spec.privileged_dim,)),
            reward=reward if reward.size else np.zeros(n, dtype=np.float32),
            reward_terms=terms if terms.shape[0] else None,
            terminated=flag(msg.terminated),
            truncated=flag(msg.truncated),
            final_env_ids=decode(msg.final_env_ids, (), "<u4").astype(np.int64),
            final_obs=decode(msg.final_obs, (spec.obs_dim,)),
            final_labels=decode(msg.final_labels, (spec.label_dim,)),
            final_privileged=decode(msg.final_privileged, (spec.privileged_dim,)),
            final_episode_length=decode(msg.final_episode_length, (), "<u4").astype(np.int64),
            mode=mode if mode.size else np.full(n, 2, dtype=np.uint8),
            terrain_level=level.astype(np.int64) if level.size else np.zeros(n, dtype=np.int64),
            step_count=int(msg.step_count),
            nonfinite_resets=int(msg.nonfinite_resets),
            head_contact=flag(msg.head_contact),
            upright_pitch=float(msg.upright_pitch) if msg.HasField("upright_pitch") else None,
            body_poses=decode(msg.body_poses, (len(spec.body_names), 7))
            if msg.HasField("body_poses")
            else None,
            mode_levels=mode_levels.astype(np.int64) if msg.HasField("mode_levels") else None,
        )

    @classmethod
    def concat(cls, parts: Sequence[StepResult], offsets: Sequence[int]) -> StepResult:
        """Join the results of shards in env order.

        Args:
            parts: One result per shard.
            offsets: Index of each shard's first env in the joined batch.
        """
        if len(parts) == 1:
            return parts[0]

        def cat(name: str) -> np.ndarray:
            return np.concatenate([getattr(p, name) for p in parts])

        terms = [p.reward_terms for p in parts]
        return cls(
            obs=cat("obs"),
            labels=cat("labels"),
            privileged=cat("privileged"),
            reward=cat("reward"),
            reward_terms=None
            if any(t is None for t in terms)
            else np.concatenate([t for t in terms if t is not None]),
            terminated=cat("terminated"),
            truncated=cat("truncated"),
            final_env_ids=np.concatenate(
                [p.final_env_ids + off for p, off in zip(parts, offsets, strict=True)]
            ),
            final_obs=cat("final_obs"),
            final_labels=cat("final_labels"),
            final_privileged=cat("final_privileged"),
            final_episode_length=cat("final_episode_length"),
            mode=cat("mode"),
            terrain_level=cat("terrain_level"),
            step_count=max(p.step_count for p in parts),
            nonfinite_resets=sum(p.nonfinite_resets for p in parts),
            head_contact=None
            if any(p.head_contact is None for p in parts)
            else np.concatenate([p.head_contact for p in parts]),
            upright_pitch=None
            if any(p.upright_pitch is None for p in parts)
            else float(np.mean([p.upright_pitch for p in parts])),
            mode_levels=None
            if any(p.mode_levels is None for p in parts)
            else np.concatenate([p.mode_levels for p in parts]),
        )


@dataclass(frozen=True)
class EvaluateResult:
    """What ``Evaluate`` returns.

    Attributes:
        metrics: Scalar results by name.
        report_json: The full report as JSON text.
        recording_rrd: A rerun recording (empty unless asked for).
    """

    metrics: dict[str, float] = field(default_factory=dict)
    report_json: str = ""
    recording_rrd: bytes = b""
