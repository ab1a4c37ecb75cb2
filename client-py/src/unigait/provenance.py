"""Where a checkpoint comes from: the git commit of the code that trained it."""

from __future__ import annotations

import subprocess
from pathlib import Path


def git_commit(repo: Path | None = None) -> str:
    """The short commit of ``repo`` (default: the working directory).

    ``+dirty`` follows it when tracked files have uncommitted changes; ``"unknown"`` outside a
    git checkout.
    """
    where = ["-C", str(repo)] if repo is not None else []

    def git(*args: str) -> str:
        out = subprocess.run(["git", *where, *args], capture_output=True, text=True, check=True)
        return out.stdout.strip()

    try:
        head = git("rev-parse", "--short", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return f"{head}+dirty" if dirty else head
