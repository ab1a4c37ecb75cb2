"""Ship a trained policy: ``assets/policies/<name>/`` with everything a user needs to trust it.

The folder holds ``policy.onnx`` (the fused estimator + actor the server runs), ``model.pt`` or
``model.ckpt`` (the Python or the Rust learner's training checkpoint, to resume or stage from),
``training.png`` and ``progress.csv`` (the curves), ``eval.json`` (every figure of the milestone
scenarios, on a seed training never used), ``reports/`` (the server's full JSON report of each
scenario) and ``MODEL_CARD.md`` (recipe, config, commit, env steps, machine, the milestone tables
and how to reproduce it). The folder is assembled under a temporary name and renamed into place
once every evaluation has succeeded, so a ship that fails leaves the shipped policy as it was.
"""

from __future__ import annotations

import csv
import json
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from unigait.averaging import describe_average
from unigait.checkpoints import SUFFIXES, export_policy, latest_checkpoint, read_checkpoint
from unigait.config import checkpoint_engine_overrides
from unigait.milestones import Milestone
from unigait.model_card import CardInputs, model_card
from unigait.provenance import git_commit
from unigait.recipes import load_recipe
from unigait.runners.recipe_runner import RECIPE_FILE


def run_folder(run_dir: Path) -> Path:
    """The folder holding the checkpoints: a recipe run's last stage begun, or ``run_dir``."""
    if not (run_dir / RECIPE_FILE).exists():
        return run_dir
    stages = sorted(p for p in run_dir.iterdir() if p.is_dir() and p.name[:2].isdigit())
    return stages[-1] if stages else run_dir


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


def _same_file(a: Path, b: Path) -> bool:
    return a.is_file() and b.is_file() and a.read_bytes() == b.read_bytes()


def _keep_reports(old: Path, built: Path) -> None:
    """Carry the old folder's other reports over when it shipped the very same checkpoint.

    Reports made beside ``ship`` (Table VI, other seeds, sim2sim) describe the checkpoint, not
    the ship: re-shipping it (a new card, say) keeps them; another checkpoint drops them.
    """
    if not any(_same_file(old / f"model{s}", built / f"model{s}") for s in SUFFIXES):
        return
    for report in sorted((old / "reports").glob("*.json")):
        if not (built / "reports" / report.name).exists():
            shutil.copyfile(report, built / "reports" / report.name)


def _swap_into_place(built: Path, folder: Path) -> None:
    """Replace ``folder`` with ``built`` (the old one is removed only once the new one is in)."""
    old = folder.with_name(f".{folder.name}.old")
    shutil.rmtree(old, ignore_errors=True)
    if folder.exists():
        folder.replace(old)
    built.replace(folder)
    shutil.rmtree(old, ignore_errors=True)


def _with_averaging(selection: str | None, checkpoint: dict[str, Any]) -> str | None:
    """The card's selection text, with the averaged iterations when the weights are a mean."""
    averaged = checkpoint.get("averaged_from")
    if not averaged:
        return selection
    sentence = describe_average([int(i) for i in averaged])
    return f"{selection}\n\n{sentence}" if selection else sentence


def ship(
    run_dir: Path,
    name: str,
    recipe: str,
    milestones: Sequence[Milestone],
    addresses: Sequence[str],
    *,
    ship_command: str,
    out_root: Path = Path("assets/policies"),
    checkpoint_path: Path | None = None,
    eval_seed: int = 1000,
    num_envs: int = 64,
    selection: str | None = None,
    lineage: str | None = None,
) -> Path:
    """Export, evaluate and document a checkpoint of ``run_dir``.

    Args:
        run_dir: A training output directory, or a recipe run's (its last stage is shipped).
        name: Folder name under ``out_root``.
        recipe: The recipe that reproduces it (checked to load).
        milestones: The milestone it is judged by first, then those it is reported against;
            their scenarios are evaluated.
        addresses: Server(s) to evaluate on (the first is used).
        ship_command: The command line that reproduces this folder (for the card).
        out_root: Where policy folders live.
        checkpoint_path: A specific checkpoint (``.pt`` or ``.ckpt``) instead of the run's
            ``model_latest.pt`` (or ``model_latest.ckpt``, a Rust learner's run).
        eval_seed: Evaluation seed (not one training or selection used).
        num_envs: Envs per scenario.
        selection: How ``checkpoint_path`` was chosen (for the model card), if it was.
        lineage: The recipe recording how this checkpoint was made, if not ``recipe``.

    Returns:
        The policy folder.
    """
    from unigait.client import Client

    load_recipe(recipe)  # a card names only recipes that resolve
    if lineage:
        load_recipe(lineage)
    source_dir = run_folder(run_dir)
    source = checkpoint_path or latest_checkpoint(source_dir)
    folder = out_root / name
    built = out_root / f".{name}.partial"
    shutil.rmtree(built, ignore_errors=True)
    (built / "reports").mkdir(parents=True)
    try:
        shutil.copyfile(source, built / f"model{source.suffix}")
        checkpoint = read_checkpoint(source)
        rows = _log_until(source_dir, built, int(checkpoint.get("iteration", 0)))
        if not rows:  # no log to cut: the run's picture as it is, if any
            for src in ("training_curves.png", "training.png"):
                if (source_dir / src).exists():
                    shutil.copyfile(source_dir / src, built / "training.png")
        export_policy(source, built / "policy.onnx")
        onnx = (built / "policy.onnx").read_bytes()
        envs: dict[str, int] = {}
        for m in milestones:
            for s in m.scenarios:
                envs.setdefault(s, m.envs_for(s, num_envs))
        evals: dict[str, dict[str, float]] = {}
        engine = checkpoint_engine_overrides(checkpoint)  # judged on its training engine
        ran_on: set[str] = set()
        with Client(addresses[0]) as client:
            for scenario, n in envs.items():
                result = client.evaluate(
                    onnx, scenario, num_envs=n, seed=eval_seed, task_overrides_toml=engine
                )
                ran_on.add(str(json.loads(result.report_json).get("physics_engine", "rapier")))
                evals[scenario] = dict(sorted(result.metrics.items()))
                report = built / "reports" / f"{scenario}_seed{eval_seed}.json"
                report.write_text(result.report_json)
        (built / "eval.json").write_text(json.dumps(evals, indent=2) + "\n")
        card = CardInputs(
            name=name,
            recipe=recipe,
            lineage=lineage,
            milestones=milestones,
            checkpoint=checkpoint,
            evals=evals,
            rows=rows,
            commit=git_commit(),
            eval_seed=eval_seed,
            num_envs=num_envs,
            ship_command=ship_command,
            selection=_with_averaging(selection, checkpoint),
            physics_engine=", ".join(sorted(ran_on)),
        )
        (built / "MODEL_CARD.md").write_text(model_card(card))
        _keep_reports(folder, built)
    except BaseException:
        shutil.rmtree(built, ignore_errors=True)
        raise
    _swap_into_place(built, folder)
    return folder
