#!/usr/bin/env python3
r"""Photograph the live view of a training run without a display.

rerun's viewer runs headless (``--headless`` on Mesa's software Vulkan driver, as
``scripts/render_recording.py`` does for recordings); the training command given after ``--``
streams into it with ``--view connect URL``; once it ends, the viewer's screenshot is scaled and
palette-compressed into ``--out``.

    .venv/bin/python scripts/render_live_view.py --out assets/pictures/live_view.png -- \
        --num-envs 64 --iterations 6 --view-every 2 \
        --init-from assets/policies/unified_flat/model.pt \
        --set 'policy.actor_hidden_dims=[256, 128, 64]' \
        --set 'policy.critic_hidden_dims=[256, 128, 64]'

Heavy (a training run and a software-rendered viewer): not part of the tests.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from render_recording import (
    RERUN,
    ROOT,
    compress,
    free_port,
    viewer_log,
    wait_listening,
)


def main() -> None:
    """Start the viewer, run the training into it, save the screenshot."""
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--size", default="1600x900")
    p.add_argument("--width", type=int, default=1200)
    p.add_argument("--settle", type=float, default=8.0)
    p.add_argument(
        "train", nargs=argparse.REMAINDER, help="-- then the train arguments"
    )
    args = p.parse_args()
    train_args = [a for a in args.train if a != "--"]
    with tempfile.TemporaryDirectory(prefix="unigait-live-view-") as tmp:
        workdir = Path(tmp)
        port = free_port()
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        log = (workdir / "viewer.log").open("wb")
        viewer = subprocess.Popen(
            [
                *(
                    str(RERUN),
                    "--headless",
                    "--renderer",
                    "vulkan",
                    "--window-size",
                    args.size,
                ),
                *("--bind", "127.0.0.1", "--port", str(port), "--hide-welcome-screen"),
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        try:
            wait_listening(port, viewer)
            command = [sys.executable, "-m", "unigait", "train", *train_args]
            command += [
                "--log-dir",
                str(workdir / "run"),
                "--quiet",
                "--view",
                "connect",
                url,
            ]
            subprocess.run(command, check=True, cwd=ROOT)
            time.sleep(args.settle)
            from rerun.experimental import ViewerClient

            shot = workdir / "shot.png"
            ViewerClient.connect(url).save_screenshot(str(shot))
            deadline = time.monotonic() + 30
            while not shot.exists() or shot.stat().st_size == 0:
                if time.monotonic() > deadline:
                    raise RuntimeError(
                        "no screenshot; the viewer's log:\n" + viewer_log(workdir)
                    )
                time.sleep(0.2)
            time.sleep(0.5)
            compress(shot, args.out, args.width)
            print(f"wrote {args.out}")
        finally:
            viewer.terminate()
            try:
                viewer.wait(10)
            except subprocess.TimeoutExpired:
                viewer.kill()
            log.close()


if __name__ == "__main__":
    main()
