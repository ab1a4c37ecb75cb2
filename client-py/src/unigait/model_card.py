"""A shipped policy's model card: what it is, how it does, how to make it again."""

from __future__ import annotations

import os
import platform
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from unigait.averaging import common_step
from unigait.milestones import Evals, Milestone
from unigait.recipes import load_recipe

#: Table III's hidden layers (actor and critic; estimator).
TABLE_III = ([512, 256, 128], [256, 128])


@dataclass(frozen=True)
class CardInputs:
    """Everything a model card says, gathered by ``ship``.

    Attributes:
        name: The policy's folder name.
        recipe: The recipe that reproduces it (``train --recipe``).
        lineage: The recipe that records how this very checkpoint was made, when that is not
            ``recipe`` (a policy trained before recipes existed).
        milestones: The milestone it is judged by first, then those it is reported against.
        checkpoint: The shipped checkpoint's contents.
        evals: Metrics per scenario on the evaluation seed.
        rows: The training log up to the shipped iteration.
        commit: The code's git commit at ship time.
        eval_seed: The evaluation seed.
        num_envs: Envs per evaluated scenario.
        ship_command: The ``ship`` command line that reproduces this folder.
        selection: How the checkpoint was chosen, when it was.
        physics_engine: The engine the evaluations ran on, as their reports name it.
    """

    name: str
    recipe: str
    lineage: str | None
    milestones: Sequence[Milestone]
    checkpoint: Mapping[str, Any]
    evals: Evals
    rows: Sequence[Mapping[str, str]]
    commit: str
    eval_seed: int
    num_envs: int
    ship_command: str
    selection: str | None = None
    physics_engine: str = "rapier"


def machine(learner: str = "torch CPU") -> str:
    """This machine in one line (cores, CPU model, what trained on it)."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()} cores, {cpu}, no GPU ({learner})"


def _fmt(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def milestone_table(
    milestone: Milestone, evals: Evals, shown: Sequence[Milestone] = ()
) -> list[str]:
    """The milestone's checks as a Markdown table, and whether it is met.

    Checks a table in ``shown`` already has are not repeated: one line says how they stand.
    """
    verdict = "met" if milestone.met(evals) else "NOT met"
    lines = [
        f"## Milestone {milestone.name}: {verdict}",
        "",
        f"{milestone.description}.",
        "",
    ]
    before = {c for m in shown for c in m.checks}
    repeated = [c for c in milestone.checks if c in before]
    if repeated:
        passed = sum(c.passes(c.value(evals)) for c in repeated)
        names = ", ".join(m.name for m in shown)
        lines += [
            f"Its checks of the tables above ({names}): {passed} of {len(repeated)} met. Its own:",
            "",
        ]
    lines += [
        "| criterion | scenario | metric | bound | value | met |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for c in milestone.checks:
        if c in before:
            continue
        v = c.value(evals)
        group = f" (at least {milestone.groups[c.group]} of the group)" if c.group else ""
        lines.append(
            f"| {c.label}{group} | `{c.scenario}` | `{c.metric}` | {c.op} {c.bound:g} | "
            f"{_fmt(v)} | {'yes' if c.passes(v) else 'no'} |"
        )
    return lines


def honest_figures(evals: Evals) -> list[str]:
    """Tracking beside a policy that does nothing, and switches counted strictly, with 95% CIs.

    Only the figures the evaluation reported appear (older servers report fewer).
    """
    lines: list[str] = []
    rows = [
        ("lin. vel. error", "lin_vel_error_mps", "m/s"),
        ("along the heading", "lin_vel_error_forward_mps", "m/s"),
        ("across the heading", "lin_vel_error_lateral_mps", "m/s"),
        ("yaw-rate error", "ang_vel_error_radps", "rad/s"),
    ]
    for mode in ("quad", "biped"):
        figures = evals.get(f"tracking_{mode}", {})
        table = []
        for label, metric, unit in rows:
            ours = figures.get(f"tracking/{mode}/{metric}")
            if ours is None:
                continue
            idle = figures.get(f"tracking/{mode}/do_nothing/{metric}")
            table.append(f"| {mode} | {label} ({unit}) | {_fmt(ours)} | {_fmt(idle)} |")
        if table:
            if not lines:
                lines += [
                    "## Tracking beside a policy that does nothing",
                    "",
                    "The do-nothing figure is the same error for zero velocity and zero yaw rate "
                    "under the same commands: a figure near it means the command is not followed.",
                    "",
                    "| mode | error | this policy | does nothing |",
                    "| --- | --- | --- | --- |",
                ]
            lines += table
    switches = []
    for scenario in ("transition_biped_to_quad", "transition_quad_to_biped"):
        m = evals.get(scenario, {})
        if "success_rate" not in m:
            continue

        def rate(key: str, m: Mapping[str, float] = m) -> str:
            if key not in m:
                return "n/a"
            low, high = m.get(f"{key}_ci95_low"), m.get(f"{key}_ci95_high")
            ci = f" [{low:.2f}, {high:.2f}]" if low is not None and high is not None else ""
            return f"{m[key]:.3f}{ci}"

        trials = int(m.get("trials", 0))
        switches.append(
            f"| `{scenario}` | {trials} | {rate('success_rate')} | {rate('strict_success_rate')} |"
        )
    if switches:
        lines += [
            "",
            "## Switches, counted strictly",
            "",
            "Strict: any fall, or any contact of a body other than the feet, within the window "
            "fails the trial (the paper claims collision-free switches). Brackets: Wilson 95% "
            "intervals.",
            "",
            "| scenario | trials | success | strict success |",
            "| --- | --- | --- | --- |",
            *switches,
        ]
    return lines


#: The paper's Table VI: (scenario, column, the paper's success rate).
TABLE_VI = (
    ("stairs_up_quad", "15 cm stairs up (q)", 1.0),
    ("stairs_down_quad", "15 cm stairs down (q)", 1.0),
    ("slope_quad", "30 deg slope (q)", 1.0),
    ("slope_biped", "30 deg slope (b)", 1.0),
    ("stairs_up_biped", "12 cm stairs up (b)", 0.6),
    ("stairs_down_biped", "15 cm stairs down (b)", 1.0),
)


def table_vi(evals: Evals) -> list[str]:
    """The paper's Table VI beside this policy's, with intervals and how the trials ended."""
    figures = evals.get("table_vi", {})
    if not figures:
        return []

    def rate(key: str) -> str:
        if key not in figures:
            return "n/a"
        low, high = figures.get(f"{key}_ci95_low"), figures.get(f"{key}_ci95_high")
        ci = f" [{low:.2f}, {high:.2f}]" if low is not None and high is not None else ""
        return f"{figures[key]:.2f}{ci}"

    lines = [
        "## Table VI",
        "",
        "Half the trials walk forward, half backward (the paper: 10 each way of 20). Brackets: "
        "Wilson 95% intervals. A trial that neither crossed nor fell timed out.",
        "",
        "| column | paper | this policy | forward | backward | fell | timed out | trials |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for scenario, column, paper in TABLE_VI:
        trials = int(figures.get(f"{scenario}/trials", 0))
        lines.append(
            f"| {column} | {paper:.1f} | {rate(f'{scenario}/success_rate')} | "
            f"{_fmt(figures.get(f'{scenario}/success_rate_forward'), 2)} | "
            f"{_fmt(figures.get(f'{scenario}/success_rate_backward'), 2)} | "
            f"{_fmt(figures.get(f'{scenario}/fall_rate'), 2)} | "
            f"{_fmt(figures.get(f'{scenario}/timeout_rate'), 2)} | {trials} |"
        )
    return lines


def _networks(checkpoint: Mapping[str, Any]) -> str:
    """The card's networks line: the checkpoint's sizes, and whether they are Table III's."""
    from unigait.config import TrainConfig, apply

    cfg = apply(TrainConfig(), dict(checkpoint.get("config", {})))
    actor, critic = list(cfg.policy.actor_hidden_dims), list(cfg.policy.critic_hidden_dims)
    estimator = list(cfg.estimator.hidden_dims)
    sizes = f"actor {actor}, critic {critic}, estimator {estimator}, {cfg.policy.activation}"
    if (actor, critic, estimator) == (TABLE_III[0], TABLE_III[0], TABLE_III[1]):
        return f"Table III ({sizes})"
    return (
        f"{sizes}: NOT Table III's (actor and critic {TABLE_III[0]}, estimator "
        f"{TABLE_III[1]}); the recipe says why"
    )


def _config_toml(checkpoint: Mapping[str, Any]) -> str:
    from unigait.config import TrainConfig, apply

    return apply(TrainConfig(), dict(checkpoint.get("config", {}))).to_toml().strip()


def model_card(card: CardInputs) -> str:
    """The model card's Markdown text."""
    checkpoint = card.checkpoint
    steps = int(checkpoint.get("total_env_steps", 0))
    iterations = int(checkpoint.get("iteration", 0))
    wall_s = sum(float(r.get("iteration_time_s", 0.0) or 0.0) for r in card.rows)
    logged = [int(float(r["iteration"])) for r in card.rows if r.get("iteration")]
    # A checkpoint counts iterations and env steps since its lineage's last start from fresh
    # networks or from weights, and the shipped log covers the last stage alone: say what each
    # figure spans rather than call it the whole recipe's cost.
    wall_span = f" (iterations {min(logged)}-{max(logged)}, the shipped log)" if logged else ""
    fixed = {s: n for m in card.milestones for s, n in m.num_envs.items()}
    envs = f"{card.num_envs} envs per scenario" + "".join(
        f" ({s}: {n})" for s, n in sorted(fixed.items())
    )
    provenance = checkpoint.get("provenance", {})
    made = (
        f"recipe `{provenance['recipe']}`, stage {provenance.get('stage')} "
        f"({provenance.get('stage_name')})"
        + (f", code `{provenance['git_commit']}`" if provenance.get("git_commit") else "")
        if provenance.get("recipe")
        else f"recipe `{card.lineage}` (the stages as they ran)"
        if card.lineage
        else f"the settings of recipe `{card.recipe}` (before checkpoints recorded their recipe)"
    )
    lines = [
        f"# Policy `{card.name}`",
        "",
        f"- trained by: {made}",
        f"- iterations: {iterations}; env steps: {steps:,} (both counted from the last start "
        f"from fresh networks or from weights); training wall time: {wall_s / 3600:.2f} h"
        f"{wall_span}",
        f"- machine: {machine(_learner(provenance))}",
        f"- shipped from code: git commit `{card.commit}`",
        f"- networks: {_networks(checkpoint)}",
        f"- evaluated on seed {card.eval_seed} (training uses seeds below 100, checkpoint "
        f"selection 2000 and up), {envs}, on the `{card.physics_engine}` physics engine (the one "
        "it was trained on); every figure here is in `eval.json`, the full reports in "
        "`reports/`",
        "",
    ]
    for k, milestone in enumerate(card.milestones):
        lines += [*milestone_table(milestone, card.evals, card.milestones[:k]), ""]
    if card.selection:
        lines += [card.selection, ""]
    honest = honest_figures(card.evals)
    if honest:
        lines += [*honest, ""]
    terrain = table_vi(card.evals)
    if terrain:
        lines += [*terrain, ""]
    biped = card.evals.get("tracking_biped", {})
    if "tracking/biped/mean_pitch_rad" in biped:
        lines += [
            f"Biped mode (`tracking_biped`): mean pitch "
            f"{biped['tracking/biped/mean_pitch_rad']:.2f} rad (upright above 1.4), head on "
            f"the ground {biped.get('head_contact_share', float('nan')):.0%} of the time.",
            "",
        ]
    lines += [
        "## Reproduce",
        "",
        f"{_starts_from(card.recipe)}, with the recipe `{card.recipe}` (every stage "
        "unattended; the same command again carries on after an interruption), then this "
        "folder:",
        "",
        "```sh",
        f"{_train_command(provenance)} --recipe {card.recipe} --log-dir runs/{card.recipe}",
        *_average_then_ship(card, checkpoint),
        "```",
        "",
    ]
    lines += [
        "Where the recipe departs from the paper, and the measurement behind each departure: "
        "`docs/src/recipes.md`.",
        "",
    ]
    if card.lineage and card.lineage != card.recipe:
        lines += [
            f"This checkpoint itself was made by the stages recorded in the recipe "
            f"`{card.lineage}` (`python -m unigait train --recipe {card.lineage} --dry-run` "
            "prints them; stages that ran on code that no longer exists are marked there).",
            "",
        ]
    stages = [str(s) for s in checkpoint.get("stages", [])]
    if stages and provenance.get("recipe"):
        lines += ["The stages this checkpoint records, in order:", ""]
        lines += [f"{i + 1}. `{s}`" for i, s in enumerate(stages)]
        lines.append("")
    lines += ["## Config", "", "```toml", _config_toml(checkpoint), "```"]
    return "\n".join(lines) + "\n"


def _average_then_ship(card: CardInputs, checkpoint: Mapping[str, Any]) -> list[str]:
    """The ship line, after the ``average`` line that makes the checkpoint when it is a mean.

    The averaged checkpoints are the numbered ones of the stage its provenance names
    (decision record 0044).
    """
    iterations = sorted(int(i) for i in checkpoint.get("averaged_from", []))
    provenance = checkpoint.get("provenance", {})
    if not iterations or "stage" not in provenance or "stage_name" not in provenance:
        return [card.ship_command]
    folder = f"runs/{card.recipe}/{int(provenance['stage']):02d}_{provenance['stage_name']}"
    step = common_step(iterations)
    if step:
        names = f"{folder}/model_{{{iterations[0]}..{iterations[-1]}..{step}}}.pt"
    else:
        names = " ".join(f"{folder}/model_{i}.pt" for i in iterations)
    averaged = f"runs/{card.recipe}/averaged_{iterations[0]}-{iterations[-1]}.pt"
    return [
        f"python -m unigait average {names} --out {averaged}",
        f"{card.ship_command} --checkpoint {averaged}",
    ]


def _is_rust(provenance: Mapping[str, Any]) -> bool:
    """Whether the Rust learner made the checkpoint (it names itself, ``unigait-learner X``)."""
    return str(provenance.get("learner", "")).startswith("unigait-learner")


def _learner(provenance: Mapping[str, Any]) -> str:
    return "unigait-learner, burn on the CPU" if _is_rust(provenance) else "torch CPU"


def _train_command(provenance: Mapping[str, Any]) -> str:
    """The command that trains like the checkpoint's learner."""
    return "unigait-learner train" if _is_rust(provenance) else "python -m unigait train"


def _starts_from(recipe: str) -> str:
    """Where a recipe's first stage starts: fresh networks, or a checkpoint in the repository."""
    start = load_recipe(recipe).stages[0].start
    return "From fresh networks" if start == "fresh" else f"From `{start}`"
