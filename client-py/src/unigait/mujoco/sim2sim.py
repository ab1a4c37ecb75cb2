"""sim2sim: an exported ONNX policy run in MuJoCo on the flat-ground scenarios of ``unigait eval``.

The scenarios and measures follow ``server/eval`` (``scenario.rs``, ``evaluate.rs``,
``transition.rs``, ``metrics.rs``) and the metrics carry the same names, so a policy's figures
in our simulator and in MuJoCo sit side by side:

- ``tracking_quad`` / ``tracking_biped``: 10 s, commands from the training ranges;
  ``tracking/<mode>/lin_vel_error_mps`` (mean |v*_xy - v_xy| in the heading frame) and
  ``ang_vel_error_radps``, counted from 1 s after a reset or mode change, biped steps only when
  upright (pitch > 1.4 rad);
- ``transition_biped_to_quad`` / ``transition_quad_to_biped``: the switch at 4 s, 3.9 s
  watched; ``success_rate`` (posture reached within 1.9 s, held 0.3 s, no base contact until
  2 s after), ``transition_time_s_mean``, ``com_height_std_m``, ...;
- ``flat_quad`` / ``flat_biped``: walk 4.5 m forward (0.8 m/s quad, 0.4 m/s biped) within 16 s;
  ``success_rate``, ``mean_progress_m``, ``terminations``.

Differences from the server's evaluation, on purpose: nominal physics (no domain
randomisation) and observation noise off unless ``noise_level`` is given. ``record`` writes a
rerun recording of env 0 in the server's layout (:mod:`unigait.mujoco.record`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from unigait.mujoco.model import PhysicsOptions, build_model
from unigait.mujoco.observation import BIPED, QUAD, ObsHistory, TaskSettings
from unigait.mujoco.vec_env import MujocoVecEnv

UPRIGHT_PITCH = 1.4
QUAD_PITCH = 0.35
HOLD_S = 0.3
TRACKING_SETTLE_S = 1.0
MODE_NAMES = {BIPED: "biped", QUAD: "quad"}


@dataclass(frozen=True)
class Sim2SimScenario:
    """One evaluation scenario.

    Attributes:
        name: Registry name (as ``unigait eval``).
        kind: ``"tracking"``, ``"transition"`` or ``"traversal"``.
        mode: Mode at the start.
        to_mode: Mode after the switch (transitions).
        vx_from: Command vx range before the switch (transitions, traversals); None = the
            training ranges.
        vx_to: Command vx range after the switch.
        duration_s: Run time (tracking) or time limit (traversal).
        switch_s: Time of the switch (transitions).
        window_s: Watched time after the switch.
        settle_s: No base contact this long after the transition completes.
        max_transition_s: The transition must complete within this.
        distance_m: Traversal success distance.
        default_envs: Envs when none are asked for.
    """

    name: str
    kind: str
    mode: int
    to_mode: int = QUAD
    vx_from: tuple[float, float] | None = None
    vx_to: tuple[float, float] | None = None
    duration_s: float = 10.0
    switch_s: float = 4.0
    window_s: float = 3.9
    settle_s: float = 2.0
    max_transition_s: float = 1.9
    distance_m: float = 4.5
    default_envs: int = 16


SCENARIOS: dict[str, Sim2SimScenario] = {
    s.name: s
    for s in (
        Sim2SimScenario("tracking_quad", "tracking", QUAD),
        Sim2SimScenario("tracking_biped", "tracking", BIPED),
        Sim2SimScenario(
            "transition_biped_to_quad", "transition", BIPED, QUAD, (-0.5, 0.5), (-0.5, 0.5)
        ),
        Sim2SimScenario(
            "transition_quad_to_biped", "transition", QUAD, BIPED, (1.5, 1.5), (0.5, 0.5)
        ),
        Sim2SimScenario("flat_quad", "traversal", QUAD, vx_from=(0.8, 0.8), duration_s=16.0),
        Sim2SimScenario("flat_biped", "traversal", BIPED, vx_from=(0.4, 0.4), duration_s=16.0),
    )
}
"""The scenarios that make sense on flat ground, by name."""


class OnnxPolicy:
    """An exported policy: ``obs_history`` f32 [B, 3, 53] -> ``actions`` f32 [B, 12].

    Args:
        path: The ONNX file.
    """

    def __init__(self, path: str | Path) -> None:
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        self.fixed_batch = inp.shape[0] if isinstance(inp.shape[0], int) else None

    def __call__(self, history: np.ndarray) -> np.ndarray:
        """Actions float32 [B, 12] for histories float32 [B, 3, 53]."""
        x = np.ascontiguousarray(history, dtype=np.float32)
        if self.fixed_batch == 1 and x.shape[0] != 1:
            return np.concatenate([self(x[i : i + 1]) for i in range(x.shape[0])])
        return np.asarray(self.session.run(None, {self.input_name: x})[0], dtype=np.float32)


def _ranges(
    settings: TaskSettings, mode: int, vx: tuple[float, float] | None
) -> tuple[tuple[float, float], ...]:
    base = settings.biped_ranges if mode == BIPED else settings.quad_ranges
    if vx is None:
        return base
    return (vx, (0.0, 0.0), (0.0, 0.0))


def first_sustained(trace: list[float], start: int, hold: int, holds: Any) -> int | None:
    """First index >= ``start`` from which ``holds`` is true for ``hold`` entries in a row."""
    run = 0
    for i in range(start, len(trace)):
        if holds(trace[i]):
            run += 1
            if run >= max(hold, 1):
                return i + 1 - max(hold, 1)
        else:
            run = 0
    return None


@dataclass
class Rollout:
    """A batch rolling a policy out: env, history, tracking and head-contact accounting."""

    env: MujocoVecEnv
    policy: OnnxPolicy
    history: ObsHistory = field(init=False)
    steps: int = 0
    lin_err: dict[int, list[float]] = field(default_factory=lambda: {BIPED: [], QUAD: []})
    ang_err: dict[int, list[float]] = field(default_factory=lambda: {BIPED: [], QUAD: []})
    head_hits: int = 0
    head_steps: int = 0
    env_steps: int = 0
    since_mode_change: np.ndarray = field(init=False)
    last_mode: np.ndarray = field(init=False)
    head_before: np.ndarray = field(init=False)
    recorder: Any = None

    def __post_init__(self) -> None:
        n = self.env.num_envs
        self.history = ObsHistory(n)
        for i in range(n):
            self.history.reset_env(i, self.env.obs[i])
        self.since_mode_change = np.zeros(n, dtype=np.int64)
        self.last_mode = self.env.mode.copy()
        self.head_before = np.zeros(n, dtype=bool)
        self.settle = round(TRACKING_SETTLE_S / self.env.settings.policy_dt)
        if self.recorder is not None:
            self.recorder.begin(self.env)

    def set_mode(self, mode: int) -> None:
        """Switch every env to ``mode`` (command redrawn), newest history entry rewritten."""
        for i in range(self.env.num_envs):
            self.env.set_mode(i, mode)
            self.history.replace_newest(i, self.env.obs[i])
        if self.recorder is not None:
            self.recorder.log_step(self.env, self.steps)

    def step(self) -> None:
        """One policy step of every env, with the tracking bookkeeping of ``Rollout::step``."""
        actions = self.policy(self.history.buffer)
        obs = self.env.step(actions)
        self.steps += 1
        if self.recorder is not None:
            self.recorder.log_step(self.env, self.steps)
        for i in range(self.env.num_envs):
            p = self.env.probe(i)
            ended = p.terminated or p.truncated
            if ended:
                self.history.reset_env(i, obs[i])
            else:
                self.history.push(i, obs[i])
            self.head_hits += int(p.head_contact and not self.head_before[i])
            self.head_steps += int(p.head_contact)
            self.head_before[i] = p.head_contact
            self.env_steps += 1
            if p.mode != self.last_mode[i] or ended:
                self.since_mode_change[i] = 0
                self.last_mode[i] = p.mode
            else:
                self.since_mode_change[i] += 1
            settled = min(int(self.since_mode_change[i]), p.episode_step) >= self.settle
            if not settled or ended:
                continue
            if p.mode == QUAD or p.pitch > UPRIGHT_PITCH:
                dv = p.command[:2] - p.velocity_xy
                self.lin_err[p.mode].append(float(np.hypot(dv[0], dv[1])))
                self.ang_err[p.mode].append(abs(float(p.command[2]) - p.yaw_rate))

    def metrics(self) -> dict[str, float]:
        """Tracking and head-contact metrics (the server's names)."""
        m: dict[str, float] = {
            "head_hits": float(self.head_hits),
            "head_contact_share": self.head_steps / max(self.env_steps, 1),
        }
        for mode, name in MODE_NAMES.items():
            if self.lin_err[mode]:
                m[f"tracking/{name}/lin_vel_error_mps"] = float(np.mean(self.lin_err[mode]))
                m[f"tracking/{name}/ang_vel_error_radps"] = float(np.mean(self.ang_err[mode]))
                m[f"tracking/{name}/samples"] = float(len(self.lin_err[mode]))
        return m


def _transition(r: Rollout, sc: Sim2SimScenario) -> dict[str, float]:
    env = r.env
    dt = env.settings.policy_dt
    switch = round(sc.switch_s / dt)
    total = switch + round(sc.window_s / dt)
    hold, settle = round(HOLD_S / dt), round(sc.settle_s / dt)
    max_transition = round(sc.max_transition_s / dt)
    n = env.num_envs
    pitch: list[list[float]] = [[env.probe(i).pitch] for i in range(n)]
    height: list[list[float]] = [[env.probe(i).height] for i in range(n)]
    end: list[tuple[int, bool] | None] = [None] * n
    while r.steps < total:
        r.step()
        if r.steps == switch:
            r.set_mode(sc.to_mode)
        for i in range(n):
            p = env.probe(i)
            if end[i] is None and (p.terminated or p.truncated):
                end[i] = (r.steps, p.terminated)
            alive = end[i] is None
            pitch[i].append(p.pitch if alive else math.nan)
            height[i].append(p.height if alive else math.nan)

    def posture(mode: int, x: float) -> bool:
        return x > UPRIGHT_PITCH if mode == BIPED else abs(x) < QUAD_PITCH

    fell = not_in_posture = successes = contacts = 0
    times, stds, ranges = [], [], []
    trials = 0
    for i in range(n):
        e = end[i]
        if e is not None and e[0] <= switch:
            fell += 1
            continue
        if not posture(sc.mode, pitch[i][switch]):
            not_in_posture += 1
            continue
        trials += 1
        done = first_sustained(pitch[i], switch, hold, lambda x: posture(sc.to_mode, x))
        contact_at = e[0] if e is not None and e[1] else None
        watch_until = min(done + settle, total) if done is not None else total
        contact = contact_at is not None and switch < contact_at <= watch_until
        ok = (
            done is not None and done - switch <= max_transition and done + settle <= total
        ) and not contact
        h = np.array([x for x in height[i][switch:] if np.isfinite(x)])
        if done is not None:
            times.append((done - switch) * dt)
        stds.append(float(h.std()) if h.size else 0.0)
        ranges.append(float(np.ptp(h)) if h.size else 0.0)
        contacts += int(contact)
        successes += int(ok)
    m: dict[str, float] = {
        "trials": float(trials),
        "successes": float(successes),
        "switched_envs": float(n),
        "fell_before_switch": float(fell),
        "not_in_posture_at_switch": float(not_in_posture),
    }
    if trials:
        m["success_rate"] = successes / trials
        m["base_contact_rate"] = contacts / trials
        m["com_height_std_m"] = float(np.mean(stds))
        m["com_height_range_m"] = float(np.mean(ranges))
        m["com_height_range_max_m"] = float(np.max(ranges))
    if times:
        m["transition_time_s_mean"] = float(np.mean(times))
        m["transition_time_s_median"] = float(np.median(times))
        m["transitions_completed"] = float(len(times))
    return m


def _traversal(r: Rollout, sc: Sim2SimScenario) -> dict[str, float]:
    env = r.env
    steps = round(sc.duration_s / env.settings.policy_dt)
    n = env.num_envs
    ended: list[str | None] = [None] * n
    best = np.zeros(n)
    while r.steps < steps and any(e is None for e in ended):
        r.step()
        for i in range(n):
            if ended[i] is not None:
                continue
            p = env.probe(i)
            progress = best[i] if p.terminated or p.truncated else p.base[0] - p.origin[0]
            best[i] = max(best[i], progress)
            if p.terminated:
                ended[i] = "terminated"
            elif progress >= sc.distance_m:
                ended[i] = "crossed"
            elif p.truncated or r.steps >= steps:
                ended[i] = "timed_out"
    crossed = sum(e == "crossed" for e in ended)
    return {
        "success_rate": crossed / n,
        "trials": float(n),
        "successes": float(crossed),
        "terminations": float(sum(e == "terminated" for e in ended)),
        "mean_progress_m": float(best.mean()),
    }


def evaluate(
    policy_path: str | Path,
    scenario: str,
    num_envs: int = 0,
    seed: int = 0,
    settings: TaskSettings | None = None,
    options: PhysicsOptions | None = None,
    record: str | Path | None = None,
) -> dict[str, float]:
    """Run ``policy_path`` on ``scenario`` in MuJoCo and measure it.

    Args:
        policy_path: The exported ONNX policy.
        scenario: A key of :data:`SCENARIOS`.
        num_envs: Trials (0 = the scenario's default).
        seed: Seed of command draws and observation noise.
        settings: Task settings (noise level included); None = the server's defaults, no noise.
        options: MuJoCo model options; None = the server's nominal physics.
        record: Write a rerun recording of env 0 to this ``.rrd`` file (needs rerun-sdk).

    Returns:
        Metric name -> value, named as ``unigait eval`` names them.
    """
    if scenario not in SCENARIOS:
        raise KeyError(f"unknown scenario {scenario!r}; known: {', '.join(SCENARIOS)}")
    sc = SCENARIOS[scenario]
    settings = settings or TaskSettings()
    run_s = sc.switch_s + sc.window_s if sc.kind == "transition" else sc.duration_s
    # The server's calm evaluation config: the episode outlasts the run, and only tracking
    # keeps the command schedule.
    settings = dataclasses.replace(
        settings, episode_length_s=max(settings.episode_length_s, run_s + 1.0)
    )
    if sc.kind != "tracking":
        settings = dataclasses.replace(settings, command_resampling_s=3600.0)
    other = BIPED if sc.mode == QUAD else QUAD
    ranges = {
        other: _ranges(settings, other, sc.vx_to if sc.to_mode == other else None),
        sc.mode: _ranges(settings, sc.mode, sc.vx_from),
    }
    env = MujocoVecEnv(
        build_model(options),
        num_envs or sc.default_envs,
        settings,
        sc.mode,
        ranges,
        seed,
    )
    recorder = None
    if record is not None:
        from unigait.mujoco.record import Sim2SimRecorder

        recorder = Sim2SimRecorder(record, name=f"sim2sim {scenario}")
    rollout = Rollout(env, OnnxPolicy(policy_path), recorder=recorder)
    if sc.kind == "transition":
        metrics = _transition(rollout, sc)
    elif sc.kind == "traversal":
        metrics = _traversal(rollout, sc)
    else:
        while rollout.steps < round(sc.duration_s / settings.policy_dt):
            rollout.step()
        metrics = {}
    metrics.update(rollout.metrics())
    if recorder is not None:
        recorder.finish()
    return metrics
