"""The paper's Fig. 2 ablation: the three arms' curves per iteration in one figure (issue 33).

    .venv/bin/python tools/plot_ablation.py assets/training/ablation --out FIG.png

Reads ``<root>/<arm>/01_ablation/progress.csv`` for the arms ``ours``, ``no_task_indicator``
and ``no_upright_indicator``. Panels against iterations: the quad linear-velocity tracking
reward and the biped base-angle reward per step (the paper's two curves), and the share of
biped env-steps spent upright (pitch above I_up's threshold), which no reward mask touches.
The reward terms are as paid: without task indicators both modes pay every term, so that arm's
curves are not masked to one mode. Prints each arm's last iteration and its final means.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from figure_style import finish_and_save
from progress_csv import rows as read_rows
from progress_csv import series, smooth

ARMS = (
    ("ours", "ours"),
    ("no_task_indicator", "w/o task indicators"),
    ("no_upright_indicator", "w/o upright indicator"),
)
PANELS = (
    ("step_reward/quad_tracking_lin_vel", "quad linear velocity tracking reward per step"),
    ("step_reward/biped_base_angle", "biped base angle reward per step"),
    ("biped_pose/upright_share", "biped mode: share of steps upright"),
)


def main() -> None:
    """Draw the figure and print where each arm stands."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="folder holding one run folder per arm")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    fig, axes = plt.subplots(1, len(PANELS), figsize=(15, 4.2))
    for index, (arm, label) in enumerate(ARMS):
        stage = args.root / arm / "01_ablation"
        if not (stage / "progress.csv").exists():
            print(f"{arm}: no progress.csv")
            continue
        rows = read_rows(stage)
        finals = []
        for ax, (key, _) in zip(axes, PANELS, strict=True):
            xs, ys = series(rows, key, x="iteration")
            ax.plot(xs, smooth(ys, 20), color=f"C{index}", label=label)
            tail = ys[-50:]
            finals.append(f"{key.split('/')[-1]} {sum(tail) / max(len(tail), 1):.4f}")
        steps = float(rows[-1]["total_env_steps"]) / 1e6
        print(
            f"{arm}: iteration {rows[-1]['iteration']} ({steps:.1f} M env steps); last 50: "
            + ", ".join(finals)
        )
    for ax, (_, title) in zip(axes, PANELS, strict=True):
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("iteration (512 envs x 24 steps)")
    finish_and_save(fig, axes, args.out)


if __name__ == "__main__":
    main()
