"""Typed view of the session ``Spec``: every tensor's row shape and its named slices."""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass
from typing import Any

import numpy as np

from unigait.client.proto import pb
from unigait.client.tensors import numpy_dtype


@dataclass(frozen=True)
class FieldSpec:
    """A named slice of a per-env vector, e.g. ``clock`` at offset 47, size 4 of ``obs``."""

    name: str
    offset: int
    size: int
    doc: str = ""

    @property
    def slice(self) -> slice:
        """The slice selecting this field in the last axis."""
        return slice(self.offset, self.offset + self.size)


@dataclass(frozen=True)
class TensorSpec:
    """What one tensor of a step result holds.

    Attributes:
        name: Tensor name (``obs``, ``labels``, ``privileged``, ``reward``, ...).
        shape: Shape of one env's row (``()`` for a scalar per env).
        dtype: numpy dtype of the values.
        fields: Named slices of the last axis, in order.
        doc: Description from the server.
    """

    name: str
    shape: tuple[int, ...]
    dtype: np.dtype[Any]
    fields: tuple[FieldSpec, ...] = ()
    doc: str = ""

    @property
    def size(self) -> int:
        """Number of values in one row."""
        return int(np.prod(self.shape, dtype=np.int64))

    @property
    def field_names(self) -> list[str]:
        """Names of the fields, in order."""
        return [f.name for f in self.fields]

    def field(self, name: str) -> FieldSpec:
        """The field called ``name``.

        Raises:
            KeyError: When there is no such field (the message lists the known ones).
        """
        for f in self.fields:
            if f.name == name:
                return f
        raise KeyError(f"{self.name} has no field {name!r}; fields: {self.field_names}")

    def slice(self, name: str) -> slice:
        """The slice of field ``name`` in the last axis, e.g. ``obs[:, spec.obs.slice("q")]``."""
        return self.field(name).slice

    @classmethod
    def from_proto(cls, msg: Any) -> TensorSpec:
        """Build from a ``unigait.v1.TensorSpec``."""
        return cls(
            name=msg.name,
            shape=tuple(int(s) for s in msg.shape),
            dtype=numpy_dtype(msg.dtype),
            fields=tuple(FieldSpec(f.name, f.offset, f.size, f.doc) for f in msg.fields),
            doc=msg.doc,
        )


@dataclass(frozen=True)
class Spec:
    """Everything a client needs to know about a session.

    Attributes:
        num_envs: Envs in the session (for a sharded session: across all shards).
        physics_dt: Physics step (s).
        decimation: Physics steps per policy step.
        policy_dt: Policy step (s).
        max_episode_steps: Policy steps before a time-out.
        action_scale: Joint target = default + action_scale * action.
        joint_names: The 12 joints, FL, FR, RL, RR x hip, thigh, calf.
        default_joint_pos: f32 [12] default joint angles (rad).
        reward_terms: Names of the reward terms, in the order of the ``reward_terms`` tensor.
        tensors: Every tensor a step result may carry, by name.
        task_config_toml: The effective task config.
        autoreset: ``"SAME_STEP"`` or ``"DISABLED"``.
        terrain: Terrain description.
        body_names: The robot's bodies, in the order of ``StepResult.body_poses`` (empty from
            older servers).
        robot_drawing_rrd: The robot's shapes as a rerun recording (asked for with
            ``SessionConfig.robot_drawing``).
        physics_engine: The engine the envs step in (``"rapier"`` or ``"articulated"``; empty
            from older servers).
        terrain_columns: The curriculum grid's column types, in order (empty on flat ground or
            a pinned tile, and from older servers).
    """

    protocol_version: str
    server_version: str
    num_envs: int
    physics_dt: float
    decimation: int
    policy_dt: float
    max_episode_steps: int
    action_scale: float
    joint_names: tuple[str, ...]
    default_joint_pos: np.ndarray
    reward_terms: tuple[str, ...]
    tensors: dict[str, TensorSpec]
    task_config_toml: str = ""
    autoreset: str = "SAME_STEP"
    terrain: str = ""
    body_names: tuple[str, ...] = ()
    robot_drawing_rrd: bytes = b""
    physics_engine: str = ""
    terrain_columns: tuple[str, ...] = ()

    def tensor(self, name: str) -> TensorSpec:
        """The spec of tensor ``name``."""
        try:
            return self.tensors[name]
        except KeyError:
            raise KeyError(f"no tensor {name!r}; tensors: {sorted(self.tensors)}") from None

    @property
    def obs(self) -> TensorSpec:
        """Spec of ``obs``: o_t [53] (cmd phi omega q qdot last_action mode clock ratio)."""
        return self.tensor("obs")

    @property
    def labels(self) -> TensorSpec:
        """Spec of ``labels``: e_t [14] (base_lin_vel foot_contact terrain_normal foot_height)."""
        return self.tensor("labels")

    @property
    def privileged(self) -> TensorSpec:
        """Spec of ``privileged`` (s_t, [10] domain-randomisation values)."""
        return self.tensor("privileged")

    @property
    def obs_dim(self) -> int:
        """Size of o_t (53)."""
        return self.obs.size

    @property
    def label_dim(self) -> int:
        """Size of e_t (14)."""
        return self.labels.size

    @property
    def privileged_dim(self) -> int:
        """Size of s_t (10)."""
        return self.privileged.size

    @property
    def num_actions(self) -> int:
        """Actions per env (12)."""
        return len(self.joint_names) or 12

    @property
    def episode_length_s(self) -> float:
        """Longest episode in seconds."""
        return self.max_episode_steps * self.policy_dt

    @property
    def pitch_index(self) -> int:
        """Column of the Euler pitch (rad, + nose down) in o_t.

        o_t's "phi" field is (gravity y, Euler pitch, gravity z): pitch is its second entry.
        """
        return self.obs.field("phi").offset + 1

    @property
    def upright_pitch(self) -> float:
        """Pitch above which the robot counts as upright in biped mode (rad; the task's I_up).

        This is ``rewards.upright_pitch`` (the paper's 1.4), where an upright curriculum ends;
        where the curriculum stands now is each step result's ``upright_pitch``.
        """
        try:
            return float(tomllib.loads(self.task_config_toml)["rewards"]["upright_pitch"])
        except (tomllib.TOMLDecodeError, KeyError) as err:
            msg = f"the session's task config has no rewards.upright_pitch ({err})"
            raise ValueError(msg) from None

    def reward_term_index(self, name: str) -> int:
        """Column of term ``name`` in the ``reward_terms`` tensor."""
        try:
            return self.reward_terms.index(name)
        except ValueError:
            raise KeyError(f"no reward term {name!r}; terms: {list(self.reward_terms)}") from None

    def with_num_envs(self, num_envs: int) -> Spec:
        """A copy with another env count (used by sharded sessions)."""
        return dataclasses.replace(self, num_envs=num_envs)

    @classmethod
    def from_proto(cls, msg: Any) -> Spec:
        """Build from a ``unigait.v1.Spec``."""
        return cls(
            protocol_version=msg.protocol_version,
            server_version=msg.server_version,
            num_envs=int(msg.num_envs),
            physics_dt=float(msg.physics_dt),
            decimation=int(msg.decimation),
            policy_dt=float(msg.policy_dt),
            max_episode_steps=int(msg.max_episode_steps),
            action_scale=float(msg.action_scale),
            joint_names=tuple(msg.joint_names),
            default_joint_pos=np.asarray(msg.default_joint_pos, dtype=np.float32),
            reward_terms=tuple(msg.reward_terms),
            tensors={t.name: TensorSpec.from_proto(t) for t in msg.tensors},
            task_config_toml=msg.task_config_toml,
            autoreset=autoreset_name(msg.autoreset),
            terrain=msg.terrain,
            body_names=tuple(msg.body_names),
            robot_drawing_rrd=bytes(msg.robot_drawing_rrd),
            physics_engine=msg.physics_engine,
            terrain_columns=tuple(msg.terrain_columns),
        )


def autoreset_name(value: int) -> str:
    """``"SAME_STEP"`` or ``"DISABLED"`` for a proto ``AutoresetMode`` value."""
    if value == pb.AUTORESET_MODE_DISABLED:
        return "DISABLED"
    return "SAME_STEP"
