#!/usr/bin/env python3
r"""Render a unigait recording to a PNG without a display, in the layout it carries.

rerun's own viewer (the `rerun` binary of the venv's rerun-sdk) runs headless (`--headless`,
an offscreen window) on Mesa's software Vulkan driver (lavapipe: Debian's
`mesa-vulkan-drivers`), so no GPU and no X server are needed. The recording is streamed to
that viewer up to the asked step with `unigait-client replay --connect --until-step` (a live stream:
the viewer follows it to its last step, the one we want; the viewer layout comes with it) and
photographed with rerun's `ViewerClient.save_screenshot`. The picture is scaled to `--width`
and palette-compressed for the README.

    .venv/bin/python scripts/render_recording.py runs/main/shipped_quad_flat.rrd \
        --step 300 --out assets/pictures/quad_gait.png

Heavy (a software-rendered viewer, ~20 s a picture on 2 cores): not part of .ci/run.
"""

from __future__ import annotations

import argparse
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RERUN = ROOT / ".venv" / "bin" / "rerun"
UNIGAIT = ROOT / "target" / "release" / "unigait-client"


def free_port() -> int:
    """A free TCP port on loopback for the headless viewer."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_listening(
    port: int, proc: subprocess.Popen[bytes], timeout_s: float = 30.0
) -> None:
    """Wait until the viewer accepts connections on ``port`` (or fail if it exited)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"the headless viewer exited with {proc.returncode}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.2)
    raise RuntimeError(f"the headless viewer did not listen on port {port}")


def compress(src: Path, dst: Path, width: int) -> None:
    """Scale the screenshot to ``width`` and palette-compress it for the README."""
    from PIL import Image

    img = Image.open(src).convert("RGB")
    if img.width > width:
        img = img.resize(
            (width, round(img.height * width / img.width)), Image.Resampling.LANCZOS
        )
    # 256 colours: the viewer's flat UI survives it, and the file shrinks about 4x.
    img = img.quantize(
        colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
    )
    dst.parent.mkdir(parents=True, exist_ok=True)
    img.save(dst, optimize=True)


def render(
    rrd: Path, out: Path, step: int | None, size: str, width: int, settle_s: float
) -> None:
    """Stream ``rrd`` up to ``step`` into a headless viewer and save its screenshot as ``out``."""
    from rerun.experimental import ViewerClient

    for tool in (RERUN, UNIGAIT):
        if not tool.exists():
            raise RuntimeError(
                f"{tool} is missing: run scripts/main.sh (or cargo build --release)"
            )
    with tempfile.TemporaryDirectory(prefix="unigait-render-") as tmp:
        workdir = Path(tmp)
        port = free_port()
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        log = (workdir / "viewer.log").open("wb")
        viewer = subprocess.Popen(
            [
                str(RERUN),
                "--headless",
                "--renderer",
                "vulkan",
                "--window-size",
                size,
                "--bind",
                "127.0.0.1",
                "--port",
                str(port),
                "--hide-welcome-screen",
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        try:
            wait_listening(port, viewer)
            replay = [str(UNIGAIT), "replay", str(rrd), "--connect", url]
            if step is not None:
                replay += ["--until-step", str(step)]
            subprocess.run(replay, check=True, capture_output=True)
            # Let the viewer ingest, lay out and render, and its start-up notices fade.
            time.sleep(settle_s)
            shot = workdir / "shot.png"
            ViewerClient.connect(url).save_screenshot(str(shot))
            deadline = time.monotonic() + 30
            while not shot.exists() or shot.stat().st_size == 0:
                if time.monotonic() > deadline:
                    raise RuntimeError(
                        "the viewer wrote no screenshot; see its log:\n"
                        + viewer_log(workdir)
                    )
                time.sleep(0.2)
            time.sleep(0.5)
            compress(shot, out, width)
        except Exception:
            print(viewer_log(workdir), file=sys.stderr)
            raise
        finally:
            viewer.terminate()
            try:
                viewer.wait(10)
            except subprocess.TimeoutExpired:
                viewer.kill()
            log.close()


def viewer_log(workdir: Path) -> str:
    """The end of the viewer's log, for error messages."""
    path = workdir / "viewer.log"
    return path.read_text(errors="replace")[-3000:] if path.exists() else ""


def main() -> int:
    """Parse the command line and render one picture."""
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "rrd",
        type=Path,
        help="a recording written by unigait (record, evaluate --record)",
    )
    p.add_argument("--out", type=Path, required=True, help="PNG to write")
    p.add_argument(
        "--step",
        type=int,
        help="show the rollout at this policy step (default: its end)",
    )
    p.add_argument(
        "--size", default="1600x900", help="viewer window in points (default 1600x900)"
    )
    p.add_argument(
        "--width", type=int, default=1600, help="picture width in pixels (default 1600)"
    )
    p.add_argument(
        "--settle", type=float, default=10.0, help="seconds the viewer renders first"
    )
    args = p.parse_args()
    if (
        shutil.which("vulkaninfo") is None
        and not Path("/usr/share/vulkan/icd.d").exists()
    ):
        print(
            "no Vulkan driver: apt-get install mesa-vulkan-drivers (software rendering)",
            file=sys.stderr,
        )
        return 2
    render(args.rrd, args.out, args.step, args.size, args.width, args.settle)
    print(f"wrote {args.out} ({args.out.stat().st_size // 1024} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
