"""The paper's learner: PPO on the actor-critic and concurrent estimator regression.

Per iteration: roll out T steps of N envs (the actor sees o_{t-2:t} and the detached estimate),
bootstrap time-outs from the critic's value of the final state, GAE, PPO, then the estimator's
MSE epochs on the same rollout.
"""

from __future__ import annotations

import math
import os
import shlex
import time
from pathlib import Path
from typing import Any, Protocol

import torch

from unigait.algorithms import PPO, EstimatorLearning
from unigait.algorithms.symmetry import ActorMirror
from unigait.config import TrainConfig, apply, checkpoint_engine, same_task
from unigait.env import BipedPoseStats, EpisodeStats, ObservationHistory, TorchStep, TorchVecEnv
from unigait.env.biped_pose import BIPED_MODE
from unigait.env.terrain_stats import TerrainLevelStats
from unigait.live_view import RobotDrawer
from unigait.modules import ActorCritic, Estimator, EstimatorActorPolicy
from unigait.storage import RolloutStorage, bootstrap_time_outs
from unigait.utils import Timers, TrainLogger

#: Config keys (by section) that shape the networks a checkpoint holds.
NETWORK_KEYS = (
    ("policy", ("actor_hidden_dims", "critic_hidden_dims", "activation", "history_length")),
    ("estimator", ("hidden_dims",)),
)


class NonFiniteUpdate(RuntimeError):
    """A training iteration produced a non-finite rollout or update (decision record 0031).

    The message names each rollout field's largest magnitude and where it sits (step, env,
    column), so the run's log says which quantity went first.
    """

    def __init__(
        self,
        iteration: int,
        phase: str,
        largest: dict[str, tuple[float, int, int, int]],
        stats: dict[str, float] | None = None,
    ) -> None:
        where = "; ".join(
            f"{k} {v:.3g} at step {t} env {e} column {c}" for k, (v, t, e, c) in largest.items()
        )
        losses = f" (update: {stats})" if stats is not None else ""
        super().__init__(f"non-finite {phase} at iteration {iteration}{losses}: {where}")
        self.iteration = iteration
        self.phase = phase
        self.largest = largest


class ScalarSink(Protocol):
    """Where each iteration's scalars go besides the CSV (TensorBoard, a live view)."""

    def log(self, scalars: dict[str, float]) -> None:
        """One iteration's scalars."""

    def close(self) -> None:
        """Flush; release what the sink holds."""


class CheckpointMismatchError(ValueError):
    """A checkpoint of other networks than this run's (its message says which ``--set``)."""


def _plain(value: object) -> object:
    """Sequences as lists (the config holds tuples, a checkpoint's TOML-loaded copy lists)."""
    return list(value) if isinstance(value, list | tuple) else value


def _toml_value(value: object) -> str:
    """``value`` as it goes on the right of a ``--set key=value``."""
    return f'"{value}"' if isinstance(value, str) else str(value)


def build_networks(
    cfg: TrainConfig, obs_dim: int, label_dim: int, privileged_dim: int, num_actions: int
) -> tuple[ActorCritic, Estimator]:
    """The actor-critic (actor input H*53 + 14, critic input 53 + 14 + 10) and the estimator."""
    history_dim = cfg.policy.history_length * obs_dim
    estimator = Estimator(history_dim, label_dim, cfg.estimator.hidden_dims, cfg.policy.activation)
    actor_critic = ActorCritic(
        actor_in=history_dim + label_dim,
        critic_in=obs_dim + label_dim + privileged_dim,
        num_actions=num_actions,
        actor_hidden=cfg.policy.actor_hidden_dims,
        critic_hidden=cfg.policy.critic_hidden_dims,
        activation=cfg.policy.activation,
        init_noise_std=cfg.policy.init_noise_std,
    )
    return actor_critic, estimator


class OnPolicyRunner:
    """Runs training against a :class:`TorchVecEnv`.

    Args:
        env: The envs (their session must return reward terms).
        cfg: The config.
        log_dir: Where CSV, PNG and checkpoints go (None: no files, no printing).
    """

    def __init__(self, env: TorchVecEnv, cfg: TrainConfig, log_dir: Path | None = None) -> None:
        self.env = env
        self.cfg = cfg
        self.device = env.device
        spec = env.spec
        # What the checkpoints record and the exported policies name (decision record 0026);
        # a server from before the spec said falls back to the task's choice.
        self.physics_engine = spec.physics_engine or checkpoint_engine({"config": cfg.to_dict()})
        self.dims = {
            "obs_dim": spec.obs_dim,
            "label_dim": spec.label_dim,
            "privileged_dim": spec.privileged_dim,
            "num_actions": spec.num_actions,
            "history_length": cfg.policy.history_length,
        }
        self.actor_critic, self.estimator = build_networks(
            cfg, spec.obs_dim, spec.label_dim, spec.privileged_dim, spec.num_actions
        )
        self.actor_critic.to(self.device)
        self.estimator.to(self.device)
        mirror = None
        if cfg.ppo.mirror_loss_coef > 0.0:
            mirror = ActorMirror.from_spec(spec, cfg.policy.history_length).to(self.device)
        self.ppo = PPO(self.actor_critic, cfg.ppo, mirror)
        self.estimator_learning = EstimatorLearning(self.estimator, cfg.estimator)
        history_dim = cfg.policy.history_length * spec.obs_dim
        self.storage = RolloutStorage(
            cfg.runner.num_steps_per_env,
            env.num_envs,
            history_dim + spec.label_dim,
            history_dim,
            spec.obs_dim + spec.label_dim + spec.privileged_dim,
            spec.label_dim,
            spec.num_actions,
            self.device,
        )
        self.history = ObservationHistory(
            env.num_envs, cfg.policy.history_length, spec.obs_dim, self.device
        )
        self.history.reset(env.last.obs)
        self.stats = EpisodeStats(env.num_envs, spec.reward_terms, self.device)
        self.biped_pose = BipedPoseStats(spec, spec.upright_pitch, self.device)
        self.iteration = 0
        self.total_env_steps = 0
        #: The commands that trained these networks, first stage first (staged training carries
        #: the parent checkpoint's list and adds its own line; a resumed run adds none): a
        #: model card's recipe.
        self.stages: list[str] = []
        #: I_up's threshold at the end of the last rollout (None before one, or when the server
        #: does not report it); saved so that a resumed run's curriculum starts there.
        self.upright_pitch: float | None = None
        #: Each env's terrain level at the end of the last rollout: saved so that a resumed
        #: curriculum run starts its envs where they were rather than on levels 0-3 again.
        self.terrain_levels: list[int] = []
        #: Each env's (quad, biped) levels, two per env (empty from older servers): a resumed
        #: run with a level per mode starts both where they were (decision record 0036).
        self.terrain_mode_levels: list[int] = []
        self.resumed = False
        #: The resumed checkpoint, and the task overrides and PPO settings it was trained with.
        self.resumed_from = ""
        self.resumed_task: dict[str, Any] = {}
        self.resumed_ppo: dict[str, Any] | None = None
        #: Where these networks come from (recipe, stage, git commit), saved with every checkpoint.
        self.provenance: dict[str, Any] = {}
        self.timers = Timers()
        self.log_dir = log_dir
        self.logger: TrainLogger | None = None
        if log_dir is not None:
            log_dir.mkdir(parents=True, exist_ok=True)
            self.logger = TrainLogger(log_dir, spec.reward_terms, cfg.runner.quiet)
        #: Each iteration's scalars also go to these (the CSV's names); closed by ``close``.
        self.sinks: list[ScalarSink] = []
        #: Draws a few envs' robots in a live view (``train --view``), None without.
        self.drawer: RobotDrawer | None = None
        if log_dir is not None and cfg.runner.tensorboard:
            from unigait.live_view import TensorBoardLog

            self.sinks.append(TensorBoardLog(log_dir))

    def policy(self) -> EstimatorActorPolicy:
        """The fused estimator + actor (mean action) for export or deployment."""
        return EstimatorActorPolicy(self.estimator, self.actor_critic.actor)

    def _bootstrapped_rewards(self, step: TorchStep) -> torch.Tensor:
        """r_t plus gamma * V(final critic input) for envs that timed out (not terminated)."""
        final_values = (
            self.actor_critic.value(step.final_critic_obs)
            if step.final_env_ids.numel()
            else step.reward.new_zeros(0)
        )
        return bootstrap_time_outs(
            step.reward,
            step.terminated,
            step.truncated,
            step.final_env_ids,
            final_values,
            self.cfg.ppo.gamma,
        )

    def rollout(self) -> dict[str, float]:
        """Collect one rollout into the storage and compute returns; return rollout statistics."""
        env, ac, timers = self.env, self.actor_critic, self.timers
        spec = env.spec
        self.storage.clear()
        step = env.last
        term_sum = torch.zeros(len(spec.reward_terms), device=self.device)
        reward_sum, biped, level, blowups = 0.0, 0.0, 0.0, 0
        terrain = TerrainLevelStats.for_env(env)  # level per terrain type and per mode
        ended: dict[str, list[torch.Tensor]] = {
            "reward": [],
            "length": [],
            "terms": [],
            "time_out": [],
        }
        drawn = self.iteration + 1
        draw = self.drawer.envs_for(drawn) if self.drawer is not None else []
        for t in range(self.cfg.runner.num_steps_per_env):
            with timers.time("inference"), torch.no_grad():
                history = self.history.flat
                actor_obs = torch.cat([history, self.estimator(history)], dim=-1)
                actions, log_prob, dist = ac.act(actor_obs)
                values = ac.value(step.critic_obs)
            with timers.time("simulation"):
                nxt = env.step(actions, draw) if draw else env.step(actions)
            if draw and self.drawer is not None:
                step_no = self.iteration * self.cfg.runner.num_steps_per_env + t + 1
                self.drawer.add(drawn, step_no, nxt.body_poses, nxt.dones.cpu().numpy())
                draw = list(self.drawer.slots)  # an ended env's slot follows another
            with timers.time("inference"), torch.no_grad():
                rewards = self._bootstrapped_rewards(nxt)
                self.storage.add(
                    actor_obs,
                    step.critic_obs,
                    step.labels,
                    actions,
                    log_prob,
                    dist.mean,
                    dist.stddev,
                    values,
                    rewards,
                    nxt.dones,
                )
                self.history.push(nxt.obs, nxt.dones)
                for k, v in self.stats.update(nxt).items():
                    ended[k].append(v)
                if nxt.reward_terms is not None:
                    term_sum += nxt.reward_terms.sum(0)
                reward_sum += float(nxt.reward.sum())
                blowups += nxt.nonfinite_resets
                biped += float((nxt.mode == BIPED_MODE).float().mean())
                self.biped_pose.add(step.mode, nxt)
                level += float(nxt.terrain_level.float().mean())
                terrain.add(nxt.terrain_level, nxt.mode)
                terrain.add_episode_ends(step.terrain_level, nxt.terrain_level, nxt.dones)
            step = nxt
        self.terrain_levels = [int(x) for x in step.terrain_level.tolist()]
        if step.mode_levels is not None:
            self.terrain_mode_levels = [int(x) for x in step.mode_levels.flatten().tolist()]
        if self.drawer is not None:
            self.drawer.flush()
        with timers.time("inference"), torch.no_grad():
            last_values = ac.value(step.critic_obs)
            self.storage.compute_returns(
                last_values, self.cfg.ppo.gamma, self.cfg.ppo.lam, self.cfg.ppo.normalize_advantage
            )
        steps = self.cfg.runner.num_steps_per_env
        samples = steps * env.num_envs
        out: dict[str, float] = {
            "mean_step_reward": reward_sum / samples,
            "terrain_level": level / steps,
            "biped_share": biped / steps,
            # Envs the server reset for a physics blow-up (decision 0035): should stay 0.
            "physics_blowups": float(blowups),
            **self.biped_pose.summary(),
            **terrain.summary(),
        }
        if step.upright_pitch is not None:
            # I_up's threshold at the end of the rollout (the task's, or its curriculum's).
            out["curriculum/upright_pitch"] = step.upright_pitch
            self.upright_pitch = step.upright_pitch
        ep = {k: torch.cat(v) for k, v in ended.items()}
        n_ep = int(ep["reward"].numel())
        out["episodes"] = float(n_ep)
        out["time_outs"] = float(ep["time_out"].sum()) if n_ep else 0.0
        out["mean_episode_reward"] = float(ep["reward"].mean()) if n_ep else math.nan
        out["mean_episode_length"] = float(ep["length"].float().mean()) if n_ep else math.nan
        per_s = ep["terms"].mean(0) / spec.episode_length_s if n_ep else None
        for i, name in enumerate(spec.reward_terms):
            out[f"episode_reward/{name}"] = float(per_s[i]) if per_s is not None else math.nan
            out[f"step_reward/{name}"] = float(term_sum[i]) / samples
        return out

    def update(self) -> dict[str, float]:
        """PPO epochs, then the estimator's epochs, on the stored rollout.

        Raises:
            NonFiniteUpdate: The rollout holds a non-finite value, or the update's losses came
                out non-finite; the networks are then not to be saved (the last checkpoint is).
        """
        rc = self.cfg.runner
        largest = self.storage.largest()
        extremes = {f"rollout/max_abs/{k}": v[0] for k, v in largest.items()}
        # Which column holds it: an observation pinned at the clip names its field this way.
        extremes |= {f"rollout/max_abs_column/{k}": float(v[3]) for k, v in largest.items()}
        if not all(math.isfinite(v) for v in extremes.values()):
            raise NonFiniteUpdate(self.iteration + 1, "rollout", largest)
        rollout_threads = torch.get_num_threads()
        if rc.update_threads > 0:
            torch.set_num_threads(rc.update_threads)
        try:
            with self.timers.time("update"):
                stats = self.ppo.update(self.storage)
                stats.update(self.estimator_learning.update(self.storage))
        finally:
            torch.set_num_threads(rollout_threads)
        if not all(math.isfinite(v) for v in stats.values()):
            raise NonFiniteUpdate(self.iteration + 1, "update", largest, stats)
        return {**stats, **extremes}

    def learn(self, num_iterations: int) -> list[dict[str, float]]:
        """Train for ``num_iterations`` more iterations; return the logged scalars of each."""
        rc = self.cfg.runner
        history: list[dict[str, float]] = []
        for i in range(num_iterations):
            self.timers.reset()
            start = time.perf_counter()
            self.actor_critic.train()
            scalars = self.rollout()
            scalars.update(self.update())
            elapsed = time.perf_counter() - start
            self.iteration += 1
            samples = rc.num_steps_per_env * self.env.num_envs
            self.total_env_steps += samples
            t = self.timers.seconds
            scalars = {
                "iteration": float(self.iteration),
                "total_env_steps": float(self.total_env_steps),
                "env_steps_per_s": samples / elapsed,
                "iteration_time_s": elapsed,
                "time_share/simulation": t["simulation"] / elapsed,
                "time_share/inference": t["inference"] / elapsed,
                "time_share/update": t["update"] / elapsed,
                **scalars,
            }
            history.append(scalars)
            for sink in self.sinks:
                sink.log(scalars)
            if self.logger is not None and self.log_dir is not None:
                self.logger.log(scalars)
                last = i == num_iterations - 1
                if self.iteration % rc.save_interval == 0 or last:
                    self.save(self.log_dir / f"model_{self.iteration}.pt")
                if self.iteration % rc.plot_interval == 0 or last:
                    self.logger.plot()
        return history

    def close(self) -> None:
        """Flush and close the scalar sinks (TensorBoard, a live view)."""
        for sink in self.sinks:
            sink.close()
        self.sinks.clear()

    def state_dict(self) -> dict[str, Any]:
        """Everything a checkpoint holds."""
        return {
            "iteration": self.iteration,
            "total_env_steps": self.total_env_steps,
            "actor_critic": self.actor_critic.state_dict(),
            "estimator": self.estimator.state_dict(),
            "optimizer": self.ppo.optimizer.state_dict(),
            "estimator_optimizer": self.estimator_learning.optimizer.state_dict(),
            "learning_rate": self.ppo.learning_rate,
            "stages": list(self.stages),
            "upright_pitch": self.upright_pitch,
            "terrain_levels": self.terrain_levels,
            "terrain_mode_levels": self.terrain_mode_levels,
            "terrain_columns": list(self.env.spec.terrain_columns),
            "config": self.cfg.to_dict(),
            "dims": self.dims,
            "provenance": dict(self.provenance),
            "physics_engine": self.physics_engine,
        }

    def save(self, path: Path) -> None:
        """Write a checkpoint (and ``model_latest.pt`` beside it).

        Each file is written under a temporary name and renamed into place, so a kill during the
        write leaves the previous file whole.
        """
        state = self.state_dict()
        for target in (path, path.with_name("model_latest.pt")):
            partial = target.with_name(f".{target.name}.partial")
            torch.save(state, partial)
            os.replace(partial, target)

    def _check_networks(self, path: str | Path, state: dict[str, Any]) -> None:
        """Refuse, naming every difference, a checkpoint whose networks are not this run's.

        Sizes and the history length would fail in ``load_state_dict`` with torch's shape
        error; another activation would load silently into a different function.
        """
        saved = state.get("config", {})
        differences = []
        for section, names in NETWORK_KEYS:
            theirs = saved.get(section, {})
            for name in names:
                if name not in theirs:
                    continue
                ours = _plain(getattr(getattr(self.cfg, section), name))
                their_value = _plain(theirs[name])
                if their_value != ours:
                    differences.append((f"{section}.{name}", their_value, ours))
        if differences:
            found = "; ".join(f"{k} = {t!r} (this run {o!r})" for k, t, o in differences)
            sets = " ".join(f"--set '{k}={_toml_value(t)}'" for k, t, _ in differences)
            raise CheckpointMismatchError(f"{path} has {found}: pass {sets}")

    def load_weights(self, path: str | Path) -> None:
        """Take the networks of a checkpoint (staged training); optimisers and counters stay.

        The adaptive learning rate starts where the checkpoint's run left it, not at the
        configured initial rate: fresh Adam moments make the first steps sign-like (every weight
        moves by about the learning rate), and at 1e-3 the first update of a trained policy
        moved it by a KL of 20 (measured: a quad_flat checkpoint lost most of its velocity
        tracking in one iteration); starting at the checkpoint's own rate (7.6e-5) the first KL was
        0.013, the rule's target being 0.01.
        """
        state = torch.load(path, map_location=self.device, weights_only=False)
        self._check_networks(path, state)
        self.actor_critic.load_state_dict(state["actor_critic"])
        self.estimator.load_state_dict(state["estimator"])
        self.stages = list(state.get("stages", []))
        if "learning_rate" in state and self.cfg.ppo.schedule == "adaptive":
            self.ppo._set_lr(float(state["learning_rate"]))

    def load(self, path: str | Path) -> None:
        """Restore networks, optimisers, counters and (adaptive schedule) the learning rate."""
        state = torch.load(path, map_location=self.device, weights_only=False)
        self._check_networks(path, state)
        self.actor_critic.load_state_dict(state["actor_critic"])
        self.estimator.load_state_dict(state["estimator"])
        self.ppo.optimizer.load_state_dict(state["optimizer"])
        self.estimator_learning.optimizer.load_state_dict(state["estimator_optimizer"])
        # The estimator has no schedule: its rate is the configured one, not the checkpoint's,
        # else a stage could never change it (the Rust learner steps at the config's too).
        for group in self.estimator_learning.optimizer.param_groups:
            group["lr"] = self.cfg.estimator.learning_rate
        # An adaptive schedule carries on from the checkpoint's rate; a fixed one is the rate the
        # user configured (how one settles a run at a rate below the adaptive rule's floor).
        if self.cfg.ppo.schedule == "adaptive":
            self.ppo._set_lr(float(state["learning_rate"]))
        else:
            self.ppo._set_lr(self.cfg.ppo.learning_rate)
        self.iteration = int(state["iteration"])
        self.total_env_steps = int(state.get("total_env_steps", 0))
        self.stages = list(state.get("stages", []))
        self.upright_pitch = state.get("upright_pitch")
        self.resumed = True
        self.resumed_from = str(path)
        saved = state.get("config", {})
        self.resumed_task = apply(TrainConfig(), {"env": saved.get("env", {})}).env.task
        self.resumed_ppo = saved.get("ppo")
        if self.logger is not None:
            self.logger.drop_after(self.iteration)

    def record_stage(self, command: str) -> None:
        """Note the command now training these networks.

        A resumed run adds nothing for flags that leave the training alone (more iterations,
        another log directory), unless its checkpoint recorded no stage at all. Resumed with other
        task overrides (a reward weight, say) it trains another task, and with other PPO settings
        (the entropy coefficient, say) another way: either is a stage, recorded with the
        checkpoint it resumed from.
        """
        if self.resumed and self.stages:
            same_ppo = self.resumed_ppo is None or self.resumed_ppo == self.cfg.to_dict()["ppo"]
            if same_ppo and same_task(self.resumed_task, self.cfg.env.task):
                return
            command = f"{command} --resume {shlex.quote(self.resumed_from)}"
        if not self.stages or self.stages[-1] != command:
            self.stages.append(command)
