"""The observation o_t (53 values) exactly as the server builds it, from a MuJoCo state.

Mirrors ``server/sim/src/task/observation.rs`` (the table) and ``env/observation_rows.rs``
(``write_observation``, ``write_task_values``): slices ``cmd, phi, omega, q, qdot, last_action,
mode, clock, ratio``; ``phi`` = (gravity y in the base frame, Euler pitch, gravity z in the base
frame); each value times its scale, plus noise when asked, clipped to +-``clip_observations``.
The gait clock is computed in float32 in the server's order of operations, so its values agree
to float32 rounding even late in an episode. The test ``tests/test_sim2sim.py`` checks this
table and every slice against the server's own output.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from unigait.mujoco.model import DEFAULT_Q
from unigait.mujoco.sim import euler_pitch, quat_to_matrix

BIPED = 1
"""Task mode code of bipedal locomotion (the server's ``TaskMode::Biped``)."""
QUAD = 2
"""Task mode code of quadrupedal locomotion."""


@dataclass(frozen=True)
class ObsField:
    """One named slice of o_t: name, size, scale per value, noise (physical units)."""

    name: str
    dim: int
    scale: tuple[float, ...]
    noise: float = 0.0


OBSERVATION: tuple[ObsField, ...] = (
    ObsField("cmd", 3, (2.0, 2.0, 0.25)),
    ObsField("phi", 3, (1.0, 1.0, 1.0), 0.05),
    ObsField("omega", 3, (0.25,) * 3, 0.2),
    ObsField("q", 12, (1.0,) * 12, 0.01),
    ObsField("qdot", 12, (0.05,) * 12, 1.5),
    ObsField("last_action", 12, (1.0,) * 12),
    ObsField("mode", 2, (1.0, 1.0)),
    ObsField("clock", 4, (1.0,) * 4),
    ObsField("ratio", 2, (1.0, 1.0)),
)
"""The server's observation table, in order."""

OBS_DIM = sum(f.dim for f in OBSERVATION)


def obs_slice(name: str) -> slice:
    """The slice of field ``name`` in o_t."""
    offset = 0
    for f in OBSERVATION:
        if f.name == name:
            return slice(offset, offset + f.dim)
        offset += f.dim
    raise KeyError(f"o_t has no field {name!r}")


OBS_SCALE = np.concatenate([np.asarray(f.scale, dtype=np.float32) for f in OBSERVATION])
OBS_NOISE = np.concatenate(
    [np.asarray(f.scale, dtype=np.float32) * np.float32(f.noise) for f in OBSERVATION]
)


@dataclass(frozen=True)
class TaskSettings:
    """The task values sim2sim needs, as in ``assets/task.toml`` (checked by the tests).

    Attributes:
        policy_dt: Policy step (s): physics dt 0.005 x decimation 4.
        decimation: Physics steps per policy step.
        action_scale: Joint target = default + action_scale * action.
        clip_actions: Actions are clipped to +- this.
        clip_observations: o_t is clipped to +- this.
        gait_period_s: Gait cycle (s).
        swing_ratio: Swing share of the cycle.
        offsets_quad: Phase offsets per foot in quad mode (trot).
        offsets_biped: Phase offsets per foot in biped mode (front feet only).
        upright_pitch: Pitch above which the robot stands on its front legs (rad).
        zero_below: Command components below this magnitude become 0.
        command_resampling_s: Commands are redrawn this often (s).
        quad_ranges: Quad command ranges (vx, vy, wz), each [low, high].
        biped_ranges: Biped command ranges.
        spawn_clearance: Lowest collider above the ground at a reset (m).
        episode_length_s: Episode length (s).
        noise_level: Observation noise level (0 = off).
    """

    policy_dt: float = 0.02
    decimation: int = 4
    action_scale: float = 0.25
    clip_actions: float = 100.0
    clip_observations: float = 100.0
    gait_period_s: float = 0.45
    swing_ratio: float = 0.4
    offsets_quad: tuple[float, ...] = (0.0, 0.5, 0.5, 0.0)
    offsets_biped: tuple[float, ...] = (0.0, 0.5, 0.0, 0.0)
    upright_pitch: float = 1.4
    zero_below: float = 0.1
    command_resampling_s: float = 10.0
    quad_ranges: tuple[tuple[float, float], ...] = ((-1.0, 1.5), (-0.5, 0.5), (-1.0, 1.0))
    biped_ranges: tuple[tuple[float, float], ...] = ((-0.5, 0.5), (-0.3, 0.3), (-0.5, 0.5))
    spawn_clearance: float = 0.02
    episode_length_s: float = 18.0
    noise_level: float = 0.0


def gait_clock(settings: TaskSettings, episode_step: int, mode: int) -> np.ndarray:
    """float32 [4] clock entries sin(2 pi (Phi + theta_i)); rear entries 0 in biped mode.

    Computed in float32 in the server's order: t = step * policy_dt, Phi = (t / T) mod 1.
    """
    f32 = np.float32
    dt = f32(f32(settings.policy_dt / settings.decimation) * f32(settings.decimation))
    t = f32(f32(episode_step) * dt)
    phase = f32(t / f32(settings.gait_period_s))
    phase = f32(phase - f32(np.floor(phase)))
    offsets = settings.offsets_biped if mode == BIPED else settings.offsets_quad
    clock = np.zeros(4, dtype=np.float32)
    for i, theta in enumerate(offsets):
        if mode == BIPED and i >= 2:
            continue
        clock[i] = np.sin(f32(f32(2.0 * np.pi) * f32(phase + f32(theta))), dtype=np.float32)
    return clock


def gravity_in_base(quat: np.ndarray) -> np.ndarray:
    """float [3] the unit gravity direction in the base frame, from (w, x, y, z)."""
    return quat_to_matrix(quat).T @ np.array([0.0, 0.0, -1.0])


@dataclass
class ObservationInputs:
    """What o_t is built from.

    Attributes:
        base_quat: float [4] trunk orientation (w, x, y, z).
        base_angvel_body: float [3] trunk angular velocity in the base frame (rad/s).
        q: float [12] joint angles (rad).
        qd: float [12] joint speeds (rad/s).
        last_action: float [12] the last (clipped) action.
        command: float [3] (vx, vy, wz).
        mode: 1 biped, 2 quad.
        episode_step: Policy steps since the episode began.
    """

    base_quat: np.ndarray
    base_angvel_body: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    last_action: np.ndarray
    command: np.ndarray
    mode: int
    episode_step: int
    default_q: np.ndarray = field(default_factory=lambda: DEFAULT_Q.copy())


def build_observation(
    x: ObservationInputs,
    settings: TaskSettings,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """o_t as the server writes it (``write_observation``).

    Args:
        x: The state and task values.
        settings: Task settings.
        rng: Noise source when ``settings.noise_level`` > 0 (uniform in [-1, 1] per value).

    Returns:
        float32 [53].
    """
    g = gravity_in_base(x.base_quat)
    raw = np.concatenate(
        [
            np.asarray(x.command, dtype=np.float64),
            [g[1], euler_pitch(x.base_quat), g[2]],
            x.base_angvel_body,
            np.asarray(x.q) - np.asarray(x.default_q),
            x.qd,
            x.last_action,
            [1.0, 0.0] if x.mode == BIPED else [0.0, 1.0],
            np.zeros(4),
            [settings.swing_ratio, 1.0 - settings.swing_ratio],
        ]
    ).astype(np.float32)
    raw[obs_slice("clock")] = gait_clock(settings, x.episode_step, x.mode)
    out = raw * OBS_SCALE
    if settings.noise_level > 0.0 and rng is not None:
        noise = OBS_NOISE * np.float32(settings.noise_level)
        out += noise * rng.uniform(-1.0, 1.0, OBS_DIM).astype(np.float32)
    clip = np.float32(settings.clip_observations)
    return np.clip(out, -clip, clip).astype(np.float32)


def rewrite_task_slices(obs: np.ndarray, x: ObservationInputs, settings: TaskSettings) -> None:
    """Rewrite only the task slices (cmd, mode, clock, ratio) of ``obs`` in place (a mode switch).

    Args:
        obs: float32 [53], changed in place.
        x: The task values (the body values are not read).
        settings: Task settings.
    """
    obs[obs_slice("cmd")] = np.asarray(x.command, dtype=np.float32) * OBS_SCALE[obs_slice("cmd")]
    obs[obs_slice("mode")] = [1.0, 0.0] if x.mode == BIPED else [0.0, 1.0]
    obs[obs_slice("clock")] = gait_clock(settings, x.episode_step, x.mode)
    obs[obs_slice("ratio")] = [settings.swing_ratio, 1.0 - settings.swing_ratio]


class ObsHistory:
    """The 3 x 53 history the policy reads (newest first), as the server's ``ObsHistory``.

    Args:
        num_envs: Envs.
        length: History length (3).
    """

    def __init__(self, num_envs: int, length: int = 3) -> None:
        self.buffer = np.zeros((num_envs, length, OBS_DIM), dtype=np.float32)

    def reset_env(self, env: int, obs: np.ndarray) -> None:
        """Fill env ``env``'s history with its first observation."""
        self.buffer[env, :] = obs

    def push(self, env: int, obs: np.ndarray) -> None:
        """Shift env ``env``'s history and put ``obs`` first."""
        self.buffer[env, 1:] = self.buffer[env, :-1].copy()
        self.buffer[env, 0] = obs

    def replace_newest(self, env: int, obs: np.ndarray) -> None:
        """Overwrite the newest entry (an observation rewritten in place)."""
        self.buffer[env, 0] = obs
