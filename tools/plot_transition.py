"""The paper's Fig. 5: CoM height through the biped -> quad switch, one curve per controller.

    .venv/bin/python tools/plot_transition.py "one policy=UNIFIED.json" \
        "two policies=TWO.json" --out FIG.png

Each argument is ``LABEL=REPORT`` where REPORT is the JSON ``python -m unigait evaluate
--scenario transition_biped_to_quad --report REPORT`` writes (with ``--biped-policy`` for the
two-policy baseline). Draws the mean base height across trials against the time from the mode
switch, with a band of one standard deviation, and prints each controller's success rates with
their Wilson 95% intervals and the height figures the report gives.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from figure_style import finish_and_save


def parse_labelled(text: str) -> tuple[str, Path]:
    """``LABEL=PATH`` -> (label, path)."""
    label, sep, path = text.partition("=")
    if not sep or not label or not path:
        raise argparse.ArgumentTypeError(f"expected LABEL=REPORT.json, got {text!r}")
    return label, Path(path)


def summary(label: str, transition: dict[str, Any]) -> str:
    """One line: trials, both success rates with their intervals, the height spread."""
    low, high = transition["success_rate_ci95"]
    strict_low, strict_high = transition["strict_success_rate_ci95"]
    return (
        f"{label}: {transition['trials']} trials, success {transition['success_rate']:.3f} "
        f"[{low:.3f}, {high:.3f}], strict {transition['strict_success_rate']:.3f} "
        f"[{strict_low:.3f}, {strict_high:.3f}], falls {transition['fall_trials']}, "
        f"height std {transition['height_std_m']['mean']:.4f} m, "
        f"range {transition['height_range_m']['mean']:.4f} m (means over trials)"
    )


def main() -> None:
    """Draw the figure and print each controller's figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reports", nargs="+", type=parse_labelled, metavar="LABEL=REPORT")
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    fig, ax = plt.subplots(figsize=(7, 4))
    for index, (label, path) in enumerate(args.reports):
        report = json.loads(path.read_text())
        transition = report["transition"]
        trace = transition["height_trace"]
        ts, mean, std = trace["t_s"], trace["mean_m"], trace["std_m"]
        colour = f"C{index}"
        ax.plot(
            ts,
            mean,
            color=colour,
            label=f"{label} (success {transition['success_rate']:.2f})",
        )
        ax.fill_between(
            ts,
            [m - s for m, s in zip(mean, std, strict=True)],
            [m + s for m, s in zip(mean, std, strict=True)],
            color=colour,
            alpha=0.2,
        )
        print(summary(label, transition))
    ax.axvline(0.0, color="grey", linestyle="--", linewidth=1)
    ax.set_xlabel("time from the switch to four legs (s)")
    ax.set_ylabel("base height (m), mean and one std. over trials")
    finish_and_save(fig, [ax], args.out)


if __name__ == "__main__":
    main()
