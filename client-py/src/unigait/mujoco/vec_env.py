"""A batch of Go2 envs in MuJoCo with the server's episode logic, for sim2sim evaluation.

What each env does per policy step, as the server's ``EnvGroup::step`` with the evaluation's calm
config: clip the action to +-100, targets = default + 0.25 a (not clamped), 4 physics steps of
the PD law, then the episode logic: terminated when the trunk's contact force exceeds 1 N,
truncated at the episode length, commands redrawn on their schedule, and o_t written
(:mod:`unigait.mujoco.observation`). Ended envs are reset in the same step (the server's
same-step autoreset). The physics are nominal (no domain randomisation: MuJoCo is the reference
here, not a training distribution); observation noise follows ``settings.noise_level``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from unigait.mujoco.model import DEFAULT_Q, Go2Model
from unigait.mujoco.observation import (
    BIPED,
    ObservationInputs,
    TaskSettings,
    build_observation,
    rewrite_task_slices,
)
from unigait.mujoco.sim import CONTACT_FORCE_N, Go2Sim, Go2State, euler_pitch


def heading_direction(rotation: np.ndarray) -> np.ndarray:
    """Unit heading (world xy): horizontal part of the body's x axis plus its z axis.

    Args:
        rotation: float [3, 3] base -> world.
    """
    h = rotation[:2, 0] + rotation[:2, 2]
    n = float(np.linalg.norm(h))
    if n * n > 1e-8:
        return h / n
    x = rotation[:2, 0]
    n = float(np.linalg.norm(x))
    return x / n if n * n > 1e-8 else np.array([1.0, 0.0])


def to_heading_frame(heading: np.ndarray, v: np.ndarray) -> np.ndarray:
    """A world vector's xy part in the heading frame (x along the heading)."""
    return np.array([heading[0] * v[0] + heading[1] * v[1], -heading[1] * v[0] + heading[0] * v[1]])


def lowest_collider_z(sim: Go2Sim) -> float:
    """Lowest point of the robot's collider bounding spheres (the server's spawn rule), m."""
    m, d = sim.model, sim.data
    lowest = math.inf
    for g in sim.go2.geom_role:
        size = m.geom_size[g]
        kind = m.geom_type[g]
        if kind == mujoco.mjtGeom.mjGEOM_BOX:
            radius = float(np.linalg.norm(size))
        elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
            radius = float(size[0] + size[1])
        else:
            radius = float(size[0])
        lowest = min(lowest, float(d.geom_xpos[g][2]) - radius)
    return lowest


@dataclass
class EnvProbe:
    """What an evaluation reads of one env after a step (the server's ``EnvProbe``)."""

    base: np.ndarray
    height: float
    pitch: float
    origin: np.ndarray
    command: np.ndarray
    velocity_xy: np.ndarray
    yaw_rate: float
    mode: int
    terminated: bool
    truncated: bool
    episode_step: int
    head_contact: bool


class MujocoVecEnv:
    """``num_envs`` robots, each its own ``MjData`` on one model.

    Args:
        go2: The compiled model.
        num_envs: Envs.
        settings: Task settings.
        mode: Task mode every episode starts in (1 biped, 2 quad).
        ranges: Command ranges (vx, vy, wz) per mode code.
        seed: Seed of command draws and noise.
    """

    def __init__(
        self,
        go2: Go2Model,
        num_envs: int,
        settings: TaskSettings,
        mode: int,
        ranges: dict[int, tuple[tuple[float, float], ...]],
        seed: int = 0,
    ) -> None:
        self.settings = settings
        self.sims = [Go2Sim(go2) for _ in range(num_envs)]
        self.num_envs = num_envs
        self.start_mode = mode
        self.ranges = ranges
        self.rng = np.random.default_rng(seed)
        self.max_episode_steps = round(settings.episode_length_s / settings.policy_dt)
        self.command_interval = round(settings.command_resampling_s / settings.policy_dt)
        self.mode = np.full(num_envs, mode)
        self.command = np.zeros((num_envs, 3))
        self.episode_step = np.zeros(num_envs, dtype=np.int64)
        self.actions = np.zeros((num_envs, 12), dtype=np.float32)
        self.origin = np.zeros((num_envs, 2))
        self.obs = np.zeros((num_envs, 53), dtype=np.float32)
        self.terminated = np.zeros(num_envs, dtype=bool)
        self.truncated = np.zeros(num_envs, dtype=bool)
        self.states: list[Go2State] = []
        self.spawn_z = self._spawn_height()
        for i in range(num_envs):
            self._reset(i)
        self.states = [s.state() for s in self.sims]
        for i in range(num_envs):
            self.obs[i] = self._observation(i)

    def _spawn_height(self) -> float:
        sim = self.sims[0]
        sim.set_state(DEFAULT_Q, base_pos=np.zeros(3))
        return self.settings.spawn_clearance - lowest_collider_z(sim)

    def draw_command(self, mode: int) -> np.ndarray:
        """A command from ``mode``'s ranges; small components become 0."""
        c = np.array([self.rng.uniform(lo, hi) for lo, hi in self.ranges[mode]])
        c[np.abs(c) < self.settings.zero_below] = 0.0
        return c

    def _reset(self, i: int) -> None:
        self.sims[i].set_state(DEFAULT_Q, base_pos=np.array([0.0, 0.0, self.spawn_z]))
        self.origin[i] = 0.0
        self.mode[i] = self.start_mode
        self.command[i] = self.draw_command(self.start_mode)
        self.episode_step[i] = 0
        self.actions[i] = 0.0

    def _observation(self, i: int) -> np.ndarray:
        s = self.states[i]
        return build_observation(self._inputs(i, s), self.settings, self.rng)

    def _inputs(self, i: int, s: Go2State) -> ObservationInputs:
        return ObservationInputs(
            base_quat=s.base_quat,
            base_angvel_body=s.rotation.T @ s.base_angvel,
            q=s.q,
            qd=s.qd,
            last_action=self.actions[i],
            command=self.command[i],
            mode=int(self.mode[i]),
            episode_step=int(self.episode_step[i]),
        )

    def step(self, actions: np.ndarray) -> np.ndarray:
        """One policy step of every env.

        Args:
            actions: float [num_envs, 12].

        Returns:
            float32 [num_envs, 53] the new observations (first ones of a new episode for envs
            that ended; see ``terminated`` and ``truncated``).
        """
        s = self.settings
        clip = s.clip_actions
        self.actions = np.clip(actions, -clip, clip).astype(np.float32)
        targets = DEFAULT_Q[None, :] + s.action_scale * self.actions.astype(np.float64)
        for i, sim in enumerate(self.sims):
            for _ in range(s.decimation):
                sim.step(targets[i])
        for i, sim in enumerate(self.sims):
            self.episode_step[i] += 1
            state = sim.state()
            finite = bool(np.all(np.isfinite(sim.data.qpos)) and np.all(np.isfinite(sim.data.qvel)))
            self.terminated[i] = not finite or state.trunk_force > CONTACT_FORCE_N
            self.truncated[i] = (
                not self.terminated[i] and self.episode_step[i] >= self.max_episode_steps
            )
            if self.terminated[i] or self.truncated[i]:
                self._reset(i)
                state = sim.state()
            elif self.episode_step[i] % self.command_interval == 0:
                self.command[i] = self.draw_command(int(self.mode[i]))
            self.states[i] = state
            self.obs[i] = self._observation(i)
        return self.obs

    def set_mode(self, i: int, mode: int, command: np.ndarray | None = None) -> None:
        """Switch env ``i`` to ``mode`` now, as the server's ``set_mode`` does.

        The command is redrawn from the new mode's ranges when the mode changes (or set to
        ``command``), the gait clock runs on, and the task slices of the current observation
        are rewritten.
        """
        changed = int(self.mode[i]) != mode
        self.mode[i] = mode
        if command is not None:
            self.command[i] = command
        elif changed:
            self.command[i] = self.draw_command(mode)
        rewrite_task_slices(self.obs[i], self._inputs(i, self.states[i]), self.settings)

    def load(
        self,
        i: int,
        state: dict[str, np.ndarray],
        mode: int,
        command: np.ndarray,
        episode_step: int,
        last_action: np.ndarray,
    ) -> np.ndarray:
        """Put env ``i`` in a given state (e.g. one the server reported) and observe it.

        Args:
            i: Env index.
            state: ``base_pos`` [3], ``base_quat`` [4] (w, x, y, z), ``base_linvel`` [3] and
                ``base_angvel`` [3] (world frame), ``q`` [12], ``qd`` [12].
            mode: 1 biped, 2 quad.
            command: float [3].
            episode_step: Policy steps since the episode began.
            last_action: float [12].

        Returns:
            float32 [53] o_t, also the env's current observation.
        """
        self.sims[i].set_state(
            state["q"],
            base_pos=state["base_pos"],
            base_quat=state["base_quat"],
            base_linvel=state["base_linvel"],
            base_angvel=state["base_angvel"],
            qd=state["qd"],
        )
        self.mode[i] = mode
        self.command[i] = command
        self.episode_step[i] = episode_step
        self.actions[i] = last_action
        self.states[i] = self.sims[i].state()
        self.obs[i] = self._observation(i)
        return self.obs[i]

    def probe(self, i: int) -> EnvProbe:
        """Read env ``i`` after the last step."""
        s = self.states[i]
        rot = s.rotation
        v = to_heading_frame(heading_direction(rot), s.base_linvel)
        return EnvProbe(
            base=s.base_pos.copy(),
            height=float(s.base_pos[2]),
            pitch=euler_pitch(s.base_quat),
            origin=self.origin[i].copy(),
            command=self.command[i].copy(),
            velocity_xy=v,
            yaw_rate=float(s.base_angvel[2]),
            mode=int(self.mode[i]),
            terminated=bool(self.terminated[i]),
            truncated=bool(self.truncated[i]),
            episode_step=int(self.episode_step[i]),
            head_contact=s.head_force > CONTACT_FORCE_N,
        )

    @property
    def biped(self) -> np.ndarray:
        """bool [num_envs] envs in biped mode."""
        return self.mode == BIPED
