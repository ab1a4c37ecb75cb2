"""Ship a trained policy: ``assets/policies/<name>/`` with everything a user needs to trust it.

The folder holds ``policy.onnx`` (the fused estimator + actor the server runs), ``model.pt`` (the
training checkpoint, to resume or stage from), ``training.png`` and ``progress.csv`` (the curves),
``eval.json`` (the milestone scenarios, evaluated on seeds training never used) and
``MODEL_CARD.md`` (preset, config, commit, env steps, wall time, machine, the milestone figures
and how to reproduce them).
"""

from __future__ import annotations

import csv
import json
import os
import platform
import shutil
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: Scenarios each preset's milestone is judged on.
MILESTONE_SCENARIOS: dict[str, tuple[str, ...]] = {
    "quad_flat": ("tracking_quad",),
    "unified_flat": (
        "tracking_quad",
        "tracking_biped",
        "transition_biped_to_quad",
        "transition_quad_to_biped",
    ),
    "unified_terrain": (
        "tracking_quad",
        "tracking_biped",
        "transition_biped_to_quad",
        "transition_quad_to_biped",
        "table_vi",
    ),
}


@dataclass(frozen=True)
class Check:
    """One milestone criterion: ``metric`` of ``scenario`` compared with ``bound``."""

    scenario: str
    metric: str
    op: str
    bound: float
    label: str

    def passes(self, value: float | None) -> bool:
        """Whether ``value`` meets the criterion (a missing value does not)."""
        if value is None:
            return False
        return value <= self.bound if self.op == "<=" else value >= self.bound


#: The milestones of the training issue (M1 quad on flat; M2 adds biped and transitions).
M1: tuple[Check, ...] = (
    Check("tracking_quad", "tracking/quad/lin_vel_error_mps", "<=", 0.15, "quad lin. vel. error"),
    Check("tracking_quad", "tracking/quad/ang_vel_error_radps", "<=", 0.2, "quad yaw-rate error"),
    Check(
        "tracking_quad", "tracking/quad/termination_rate", "<=", 0.05, "quad episodes terminated"
    ),
)
M2: tuple[Check, ...] = (
    *M1,
    Check("tracking_biped", "tracking/biped/upright_share", ">=", 0.9, "biped upright share"),
    Check("tracking_biped", "tracking/biped/lin_vel_error_mps", "<=", 0.2, "biped lin. vel. error"),
    Check("transition_biped_to_quad", "success_rate", ">=", 0.9, "biped -> quad success"),
    Check("transition_quad_to_biped", "success_rate", ">=", 0.9, "quad -> biped success"),
)
MILESTONES: dict[str, tuple[str, tuple[Check, ...]]] = {
    "quad_flat": ("M1", M1),
    "unified_flat": ("M2", M2),
    "unified_terrain": ("M2", M2),
}


def _git_commit(repo: Path) -> str:
    try:
        out = subprocess.run(
            ["git", "-C", str(repo), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        )
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()} cores, {cpu}, no GPU (torch CPU)"


def _progress(run_dir: Path) -> list[dict[str, str]]:
    path = run_dir / "progress.csv"
    if not path.exists():
        return []
    with path.open() as f:
        return list(csv.DictReader(f))


def _log_until(run_dir: Path, folder: Path, iteration: int) -> list[dict[str, str]]:
    """The run's log up to the shipped checkpoint's ``iteration``, kept beside the policy.

    Written to ``folder`` as ``progress.csv`` and drawn as ``training.png``: a run goes on after
    the checkpoint it ships, and its later rows would describe a policy that is not the one
    shipped.
    """
    from unigait.utils.logger import TrainLogger

    rows = [r for r in _progress(run_dir) if int(float(r.get("iteration") or 0)) <= iteration]
    if not rows:
        return []
    with (folder / "progress.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    TrainLogger(folder, ()).plot()
    (folder / "training_curves.png").replace(folder / "training.png")
    return rows


def metric_of(evals: dict[str, dict[str, float]], check: Check) -> float | None:
    """The figure ``check`` judges, if the evaluation has it."""
    value = evals.get(check.scenario, {}).get(check.metric)
    return None if value is None else float(value)


def model_card(
    name: str,
    preset: str,
    checkpoint: dict[str, Any],
    evals: dict[str, dict[str, float]],
    rows: Sequence[dict[str, str]],
    commit: str,
    eval_seed: int,
    num_envs: int,
    run_dir: str | None = None,
    selection: str | None = None,
) -> str:
    """The model card's Markdown text.

    ``run_dir`` is the training output shipped from; ``selection`` says how the checkpoint was
    chosen, when it was.
    """
    steps = int(checkpoint.get("total_env_steps", 0))
    iterations = int(checkpoint.get("iteration", 0))
    wall_s = sum(float(r.get("iteration_time_s", 0.0) or 0.0) for r in rows)
    logged = [int(r["iteration"]) for r in rows if r.get("iteration")]
    # A checkpoint counts iterations and env steps since its lineage's last `--init-from`, and the
    # shipped log covers the last stage alone: say what each figure spans rather than call it
    # the whole recipe's cost.
    wall_span = f" (iterations {min(logged)}-{max(logged)}, the shipped log)" if logged else ""
    milestone, checks = MILESTONES.get(preset, ("-", ()))
    lines = [
        f"# Policy `{name}`",
        "",
        f"- preset: `{preset}` (`python -m unigait train --preset {preset}`)",
        f"- iterations: {iterations}; env steps: {steps:,} (both counted from the last fresh "
        f"start or `--init-from`); training wall time: {wall_s / 3600:.2f} h{wall_span}",
        f"- machine: {_machine()}",
        f"- code: git commit `{commit}`",
        f"- networks: {_networks(checkpoint)}",
        f"- evaluated on seed {eval_seed} (training used seeds below 100), {num_envs} envs per "
        "scenario",
        "",
        f"## Milestone {milestone}",
        "",
        "| criterion | scenario | metric | bound | value | met |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for c in checks:
        v = metric_of(evals, c)
        shown = "n/a" if v is None else f"{v:.3f}"
        lines.append(
            f"| {c.label} | `{c.scenario}` | `{c.metric}` | {c.op} {c.bound} | {shown} | "
            f"{'yes' if c.passes(v) else 'no'} |"
        )
    if selection:
        lines += ["", selection]
    biped = evals.get("tracking_biped", {})
    if "tracking/biped/mean_pitch_rad" in biped:
        # Progress the milestone table does not show until the robot is upright.
        line = (
            f"Biped mode (`tracking_biped`): mean pitch "
            f"{biped['tracking/biped/mean_pitch_rad']:.2f} rad (upright above 1.4), head on "
            f"the ground {biped.get('head_contact_share', float('nan')):.0%} of the time."
        )
        if "tracking/biped/lin_vel_error_lateral_mps" in biped:
            # Which way the biped misses its command: a gait that walks only forward and back
            # leaves the whole lateral command as error.
            line += (
                " Its velocity error along the heading "
                f"{biped['tracking/biped/lin_vel_error_forward_mps']:.3f} m/s, across it "
                f"{biped['tracking/biped/lin_vel_error_lateral_mps']:.3f} m/s."
            )
        lines += ["", line]
    stages = [str(s) for s in checkpoint.get("stages", [])]
    if stages:
        recipe = (
            "The commands that trained it, in order (each later stage starts from the one "
            "before's checkpoint: with `--init-from`, or with `--resume` where the run went on "
            "with other task overrides or PPO settings):"
        )
    else:  # checkpoints written before the runner kept its stages
        recipe = "The preset's command (this checkpoint does not record its stages):"
        stages = [f"python -m unigait train --preset {preset} --log-dir runs/{name}"]
    lines += [
        "",
        "## Reproduce",
        "",
        recipe,
        "",
        "```sh",
        *stages,
        f"python -m unigait ship --run-dir {run_dir or f'runs/{name}'} --name {name} "
        f"--preset {preset}",
        "```",
        "",
        "Training resumes from `model.pt` with `--resume`; a later stage starts from it with "
        "`--init-from`.",
        "",
        "## Config",
        "",
        "```toml",
        _config_toml(checkpoint),
        "```",
    ]
    return "\n".join(lines) + "\n"


#: Table III's hidden layers (actor and critic; estimator).
TABLE_III = ([512, 256, 128], [256, 128])


def _networks(checkpoint: dict[str, Any]) -> str:
    """The card's networks line: the checkpoint's sizes, and whether they are Table III's."""
    from unigait.config import TrainConfig, apply

    cfg = apply(TrainConfig(), checkpoint.get("config", {}))
    actor, critic = list(cfg.policy.actor_hidden_dims), list(cfg.policy.critic_hidden_dims)
    estimator = list(cfg.estimator.hidden_dims)
    sizes = f"actor {actor}, critic {critic}, estimator {estimator}, {cfg.policy.activation}"
    if (actor, critic, estimator) == (TABLE_III[0], TABLE_III[0], TABLE_III[1]):
        return f"Table III ({sizes})"
    return (
        f"{sizes}: NOT Table III's (actor and critic {TABLE_III[0]}, estimator "
        f"{TABLE_III[1]}); the preset says why (measured faster per hour on this machine)"
    )


def _config_toml(checkpoint: dict[str, Any]) -> str:
    from unigait.config import TrainConfig, apply

    return apply(TrainConfig(), checkpoint.get("config", {})).to_toml().strip()


def ship(
    run_dir: Path,
    name: str,
    preset: str,
    addresses: Sequence[str],
    out_root: Path = Path("assets/policies"),
    checkpoint_path: Path | None = None,
    eval_seed: int = 1000,
    num_envs: int = 64,
    selection: str | None = None,
) -> Path:
    """Export, evaluate and document the latest checkpoint of ``run_dir``.

    Args:
        run_dir: A training output directory (``model_latest.pt``, ``progress.csv``, PNG).
        name: Folder name under ``out_root``.
        preset: The preset it was trained with (picks the milestone scenarios).
        addresses: Server(s) to evaluate on (the first is used).
        out_root: Where policy folders live.
        checkpoint_path: A specific checkpoint instead of ``model_latest.pt``.
        eval_seed: Evaluation seed (not one training used).
        num_envs: Envs per scenario.
        selection: How ``checkpoint_path`` was chosen (for the model card), if it was.

    Returns:
        The policy folder.
    """
    import torch

    from unigait.client import Client
    from unigait.export import export_mismatch, export_onnx, load_policy

    source = checkpoint_path or run_dir / "model_latest.pt"
    folder = out_root / name
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(source, folder / "model.pt")
    checkpoint = torch.load(source, map_location="cpu", weights_only=False)
    rows = _log_until(run_dir, folder, int(checkpoint.get("iteration", 0)))
    if not rows:  # no log to cut: the run's picture as it is, if any
        for src in ("training_curves.png", "training.png"):
            if (run_dir / src).exists():
                shutil.copyfile(run_dir / src, folder / "training.png")
    policy, dims = load_policy(source)
    export_onnx(policy, folder / "policy.onnx", dims["history_length"], dims["obs_dim"])
    diff = export_mismatch(policy, folder / "policy.onnx")
    if diff > 1e-5:
        raise RuntimeError(f"the exported graph differs from torch by {diff:.2e} (relative)")
    onnx = (folder / "policy.onnx").read_bytes()
    evals: dict[str, dict[str, float]] = {}
    with Client(addresses[0]) as client:
        for scenario in MILESTONE_SCENARIOS.get(preset, ("tracking_quad",)):
            result = client.evaluate(onnx, scenario, num_envs=num_envs, seed=eval_seed)
            evals[scenario] = dict(sorted(result.metrics.items()))
    (folder / "eval.json").write_text(json.dumps(evals, indent=2) + "\n")
    card = model_card(
        name,
        preset,
        checkpoint,
        evals,
        rows,
        _git_commit(Path.cwd()),
        eval_seed,
        num_envs,
        str(run_dir),
        selection,
    )
    (folder / "MODEL_CARD.md").write_text(card)
    return folder
