"""The Rust and the Python learner on one recipe, learning curves in one figure (issue 38).

    .venv/bin/python tools/plot_learner_comparison.py \
        --out docs/src/pictures/learners_quad_flat.png \
        rust_s1=assets/training/learners_quad_flat/rust_s1 ...

Each RUN is ``label=folder`` with the stage's ``progress.csv`` and, if the stage checked its
milestone, ``validation.jsonl``. Labels starting with ``rust`` are drawn solid, the others
dashed. Panels against env steps: the mean reward per step, the quad velocity-tracking reward
per step, and the milestone checks' quad velocity error (M1's bound 0.15 m/s drawn). Prints, per
run, the env steps of the first check that met the milestone.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from figure_style import finish_and_save
from progress_csv import rows as read_rows
from progress_csv import series, smooth

LIN_VEL = "tracking/quad/lin_vel_error_mps"
KEYS = ("mean_step_reward", "step_reward/quad_tracking_lin_vel")


def _checks(folder: Path, steps_per_iteration: float) -> list[tuple[float, float, bool]]:
    path = folder / "validation.jsonl"
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        row = json.loads(line)
        error = row["evals"]["tracking_quad"][LIN_VEL]
        met = row["criteria_met"] == row["criteria"]
        out.append((row["iteration"] * steps_per_iteration, error, met))
    return out


def main() -> None:
    """Draw the figure and print each run's first met milestone check."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", metavar="LABEL=FOLDER")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for index, spec in enumerate(args.runs):
        color = f"C{index}"
        label, folder = spec.split("=", 1)
        rows = read_rows(Path(folder))
        style = "-" if label.startswith("rust") else "--"
        first = rows[0]
        per_iteration = float(first["total_env_steps"]) / float(first["iteration"])
        for ax, key in zip(axes[:2], KEYS, strict=True):
            xs, ys = series(rows, key)
            ax.plot([x / 1e6 for x in xs], smooth(ys, 10), style, color=color, label=label)
        checks = _checks(Path(folder), per_iteration)
        if checks:
            axes[2].plot(
                [c[0] / 1e6 for c in checks],
                [c[1] for c in checks],
                style + "o",
                color=color,
                label=label,
            )
            met = next((c[0] for c in checks if c[2]), None)
            print(
                f"{label}: M1 first met at {met / 1e6:.2f} M env steps"
                if met
                else f"{label}: M1 not met in {len(checks)} checks"
            )
        else:
            print(f"{label}: no validation.jsonl")
    axes[0].set_title("mean reward per step (10-iteration mean)")
    axes[1].set_title("quad velocity tracking reward per step")
    axes[2].set_title("milestone checks: quad velocity error (m/s)")
    axes[2].axhline(0.15, color="grey", lw=0.8)
    for ax in axes:
        ax.set_xlabel("env steps (M)")
    finish_and_save(fig, axes, args.out)


if __name__ == "__main__":
    main()
