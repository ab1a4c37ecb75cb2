"""Training output: a console block per iteration, a CSV of scalars, a PNG of the curves."""

from __future__ import annotations

import csv
import math
import os
import time
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: Curves drawn in the PNG (CSV column, panel title); missing columns are skipped.
PLOT_PANELS: tuple[tuple[str, str], ...] = (
    ("mean_episode_reward", "mean episode reward"),
    ("mean_step_reward", "mean reward per step"),
    ("mean_episode_length", "mean episode length (steps)"),
    ("step_reward/quad_tracking_lin_vel", "quad lin. velocity tracking (per step)"),
    ("step_reward/biped_base_angle", "biped base angle (per step)"),
    ("step_reward/biped_tracking_lin_vel", "biped lin. velocity tracking (per step)"),
    ("terrain_level", "mean terrain level"),
    ("biped_pose/pitch", "biped mode: mean pitch (rad)"),
    ("biped_pose/head_contact_share", "biped mode: share with head on the ground"),
    ("env_steps_per_s", "env steps/s"),
    ("learning_rate", "learning rate"),
    ("value_loss", "value loss"),
    ("estimator_loss", "estimator MSE"),
)


class Timers:
    """Wall-time accumulators by name (reset per iteration)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)

    @contextmanager
    def time(self, name: str) -> Iterator[None]:
        """Add the duration of the ``with`` block to ``name``."""
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - start

    def reset(self) -> None:
        """Zero every accumulator."""
        self.seconds.clear()


class TrainLogger:
    """Writes ``progress.csv`` and ``training_curves.png`` into ``log_dir`` and prints progress.

    Args:
        log_dir: Output directory.
        term_names: Reward term names (printed in this order).
        quiet: One line per iteration instead of the full block.
    """

    def __init__(self, log_dir: Path, term_names: tuple[str, ...], quiet: bool = False) -> None:
        self.log_dir = log_dir
        self.term_names = term_names
        self.quiet = quiet
        self.csv_path = log_dir / "progress.csv"
        self.plot_path = log_dir / "training_curves.png"
        self.columns: list[str] | None = None
        self.history: dict[str, list[float]] = defaultdict(list)
        if self.csv_path.is_file():  # resumed run: keep the old rows in the plot
            with self.csv_path.open() as f:
                reader = csv.DictReader(f)
                self.columns = list(reader.fieldnames or [])
                for row in reader:
                    for k, v in row.items():
                        self.history[k].append(float(v) if v not in ("", None) else math.nan)

    def log(self, scalars: dict[str, float]) -> None:
        """Print, append a CSV row and remember the values for the plot."""
        if self.columns is None:
            self.columns = list(scalars)
            with self.csv_path.open("w", newline="") as f:
                csv.writer(f).writerow(self.columns)
        elif new := [c for c in scalars if c not in self.columns]:
            self._add_columns(new)
        with self.csv_path.open("a", newline="") as f:
            csv.writer(f).writerow([_fmt(scalars.get(c, math.nan)) for c in self.columns])
        for c in self.columns:
            self.history[c].append(scalars.get(c, math.nan))
        print(self._line(scalars) if self.quiet else self._block(scalars), flush=True)

    def _read_rows(self) -> list[list[str]]:
        """The CSV's data rows as written (header left out)."""
        with self.csv_path.open() as f:
            return list(csv.reader(f))[1:]

    def _rewrite(self, rows: list[list[str]]) -> None:
        """Replace the CSV by header + ``rows``.

        Written to a temporary file first: an interrupted rewrite leaves the old log whole.
        """
        assert self.columns is not None
        tmp = self.csv_path.with_suffix(".csv.tmp")
        with tmp.open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(self.columns)
            w.writerows(rows)
        os.replace(tmp, self.csv_path)

    def _add_columns(self, new: list[str]) -> None:
        """A resumed run that logs more than the run it resumes: widen the CSV, old rows empty."""
        assert self.columns is not None
        old_rows = self._read_rows()
        self.columns += new
        self._rewrite([row + [""] * len(new) for row in old_rows])
        for c in new:
            self.history[c] = [math.nan] * len(old_rows)

    def drop_after(self, iteration: int) -> None:
        """Forget the rows logged past ``iteration``.

        A run resumed from an older checkpoint than its log's last row trains those iterations
        again; without this the log holds them twice and the plot doubles back.
        """
        if self.columns is None or "iteration" not in self.columns:
            return
        its = self.history["iteration"]
        keep = [i for i, it in enumerate(its) if not it > iteration]
        if len(keep) == len(its):
            return
        rows = self._read_rows()
        self._rewrite([rows[i] for i in keep])
        for c in list(self.history):
            self.history[c] = [self.history[c][i] for i in keep]

    def _line(self, s: dict[str, float]) -> str:
        return (
            f"it {int(s['iteration']):5d} | {s['env_steps_per_s']:7.0f} steps/s | "
            f"reward/step {s['mean_step_reward']:+.4f} | ep. reward {s['mean_episode_reward']:+.3f}"
            f" | ep. len {s['mean_episode_length']:6.1f} | quad track "
            f"{s.get('step_reward/quad_tracking_lin_vel', math.nan):.4f} | biped pitch "
            f"{s.get('biped_pose/pitch', math.nan):.2f} head "
            f"{s.get('biped_pose/head_contact_share', math.nan):.2f} I_up > "
            f"{s.get('curriculum/upright_pitch', math.nan):.2f}"
            f" | sim/inf/upd {s['time_share/simulation']:.0%}/"
            f"{s['time_share/inference']:.0%}/{s['time_share/update']:.0%}"
        )

    def _block(self, s: dict[str, float]) -> str:
        pad = 42
        rows = [
            ("iteration", f"{int(s['iteration'])}"),
            ("env steps (total)", f"{int(s['total_env_steps'])}"),
            ("env steps/s (whole iteration)", f"{s['env_steps_per_s']:.0f}"),
            ("iteration time", f"{s['iteration_time_s']:.2f} s"),
            (
                "time share sim/inference/update",
                f"{s['time_share/simulation']:.0%} / {s['time_share/inference']:.0%} / "
                f"{s['time_share/update']:.0%}",
            ),
            ("mean episode reward", f"{s['mean_episode_reward']:.4f}"),
            ("mean reward per step", f"{s['mean_step_reward']:.5f}"),
            ("mean episode length (steps)", f"{s['mean_episode_length']:.1f}"),
            ("episodes ended (time-outs)", f"{int(s['episodes'])} ({int(s['time_outs'])})"),
            ("mean terrain level", f"{s['terrain_level']:.2f}"),
            ("share of biped mode", f"{s['biped_share']:.3f}"),
            (
                "biped mode: pitch / upright / head down",
                f"{s.get('biped_pose/pitch', math.nan):.2f} rad / "
                f"{s.get('biped_pose/upright_share', math.nan):.0%} / "
                f"{s.get('biped_pose/head_contact_share', math.nan):.0%}",
            ),
            (
                "upright indicator threshold",
                f"{s.get('curriculum/upright_pitch', math.nan):.2f} rad",
            ),
            ("value / surrogate loss", f"{s['value_loss']:.4f} / {s['surrogate_loss']:.4f}"),
            ("estimator MSE", f"{s['estimator_loss']:.5f}"),
            (
                "KL / learning rate / action std",
                f"{s['kl']:.4f} / {s['learning_rate']:.2e} / {s['action_std']:.3f}",
            ),
        ]
        lines = ["#" * 80] + [f"{k + ':':>{pad}} {v}" for k, v in rows]
        lines.append(f"{'reward term':>{pad}}  episode mean   per step")
        for name in self.term_names:
            ep = s.get(f"episode_reward/{name}", math.nan)
            st = s.get(f"step_reward/{name}", math.nan)
            lines.append(f"{name:>{pad}}  {ep:+12.5f} {st:+10.6f}")
        return "\n".join(lines)

    def plot(self) -> None:
        """Redraw ``training_curves.png`` (matplotlib, Agg backend)."""
        import matplotlib

        matplotlib.use("Agg")
        from matplotlib import pyplot as plt

        panels = [(c, t) for c, t in PLOT_PANELS if c in self.history]
        if not panels or "iteration" not in self.history:
            return
        cols = 3
        rows = math.ceil(len(panels) / cols)
        fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.8 * rows), squeeze=False)
        x = self.history["iteration"]
        for ax, (col, title) in zip(axes.flat, panels, strict=False):
            ax.plot(x, self.history[col], lw=1.2)
            ax.set_title(title, fontsize=9)
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
        for ax in list(axes.flat)[len(panels) :]:
            ax.axis("off")
        fig.supxlabel("iteration", fontsize=9)
        fig.tight_layout()
        fig.savefig(self.plot_path, dpi=90)
        plt.close(fig)


def _fmt(v: float) -> str:
    return "" if isinstance(v, float) and math.isnan(v) else f"{v:.6g}"
