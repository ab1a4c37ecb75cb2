"""What ``train --view`` costs a training run: the same run with and without the view, alternated.

One local server; each repetition trains a fresh run without a view and one with
``--view save`` drawing 4 envs every 10th iteration (the defaults), both for 11 iterations at
512 envs; the first iteration of each (session warm-up, torch's first passes) is left out, so
the 10 measured iterations of a viewed run hold exactly one drawn iteration, as a long run has.
Alternating the two cancels the machine's drift. Prints (JSON, after the runs' own lines) the
median and mean iteration time of each, the cost, the drawn iteration's extra time and the
time the learner spends in the view's calls.

    .venv/bin/python scripts/bench_live_view.py [--envs 512] [--reps 2]
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

from unigait import live_view
from unigait.client import open_session
from unigait.config import load_config
from unigait.live_view import ViewTarget
from unigait.runners import train
from unigait.server_process import LocalServer

#: Wall seconds spent in the view's own calls (curves, poses), by call.
SPENT: dict[str, float] = defaultdict(float)


def _timed(cls: type, name: str) -> None:
    original: Callable[..., Any] = getattr(cls, name)

    def timed(self: object, *args: object, **kwargs: object) -> Any:
        start = time.perf_counter()
        try:
            return original(self, *args, **kwargs)
        finally:
            SPENT[f"{cls.__name__}.{name}"] += time.perf_counter() - start

    setattr(cls, name, timed)


for _cls, _name in (
    (live_view.LiveView, "log"),
    (live_view.RobotDrawer, "add"),
    (live_view.RobotDrawer, "flush"),
):
    _timed(_cls, _name)


def run(address: str, envs: int, out: Path, view: ViewTarget | None) -> list[float]:
    """Train 11 iterations of a fresh run; each iteration's time (s)."""
    cfg = load_config(
        None,
        [
            f"env.num_envs={envs}",
            "runner.max_iterations=11",
            f"runner.log_dir={json.dumps(str(out))}",
            "runner.quiet=true",
            "runner.save_interval=1000",
            "runner.plot_interval=1000",
        ],
    )
    history = train(cfg, lambda c: open_session(address, c), view=view)
    return [h["iteration_time_s"] for h in history]


def main() -> None:
    """Alternate runs with and without the view; print the figures as JSON."""
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--envs", type=int, default=512)
    p.add_argument("--reps", type=int, default=2)
    p.add_argument("--view-envs", type=int, default=4)
    p.add_argument("--view-every", type=int, default=10)
    args = p.parse_args()
    times: dict[str, list[list[float]]] = {"plain": [], "view": []}
    with tempfile.TemporaryDirectory() as tmp, LocalServer() as server:
        for rep in range(args.reps):
            for name in ("plain", "view"):
                out = Path(tmp) / f"{name}{rep}"
                view = None
                if name == "view":
                    rrd = str(out) + ".rrd"
                    view = ViewTarget("save", rrd, args.view_envs, args.view_every)
                times[name].append(run(server.address, args.envs, out, view)[1:])
        rrd_bytes = sum(f.stat().st_size for f in Path(tmp).glob("*.rrd")) / args.reps
    mean = {k: statistics.mean(t for r in v for t in r) for k, v in times.items()}
    # Medians: another process's burst (a build on a shared machine) slows a few iterations
    # by 5-10x, which a mean of 20 carries and a median does not.
    median = {k: statistics.median(t for r in v for t in r) for k, v in times.items()}
    drawn = [
        r[args.view_every - 2] for r in times["view"]
    ]  # iteration 10: index 8 of 2..11
    undrawn = [
        t for r in times["view"] for i, t in enumerate(r) if i != args.view_every - 2
    ]
    print(
        json.dumps(
            {
                "envs": args.envs,
                "reps": args.reps,
                "iteration_s": times,
                "median_iteration_s": median,
                "cost": median["view"] / median["plain"] - 1.0,
                "mean_iteration_s": mean,
                "cost_of_means": mean["view"] / mean["plain"] - 1.0,
                "drawn_iteration_extra_s": statistics.mean(drawn)
                - statistics.mean(undrawn),
                "curves_only_cost": statistics.mean(undrawn) / mean["plain"] - 1.0,
                "rrd_bytes_per_run": rrd_bytes,
                # The view's calls in the learner over all viewed runs' 11 iterations.
                "view_calls_s_per_iteration": {
                    k: v / (11 * args.reps) for k, v in SPENT.items()
                },
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
