"""Training checkpoints of either learner.

The Python learner writes ``model_*.pt`` (torch), the Rust learner ``model_*.ckpt``
(``unigait-learner``, docs/src/rust-learner.md).

``ship`` and checkpoint selection read both through :func:`read_checkpoint` (the fields a model
card and the engine choice need, with the Python learner's keys) and :func:`export_policy` (the
fused ONNX the server serves). A ``.ckpt`` is exported by the Rust learner's own ``export``:
its networks are burn records, which this package does not load.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import tomllib
from pathlib import Path
from typing import Any

SUFFIXES = (".pt", ".ckpt")
"""Checkpoint file suffixes: the Python learner's first."""

_RUST_MAGIC = b"UGLCKPT1"


class CheckpointError(ValueError):
    """A checkpoint that cannot be read or exported, with the file named."""


def latest_checkpoint(folder: Path) -> Path:
    """``folder``'s ``model_latest.pt``, else its ``model_latest.ckpt`` (the former if neither)."""
    for suffix in SUFFIXES:
        path = folder / f"model_latest{suffix}"
        if path.exists():
            return path
    return folder / f"model_latest{SUFFIXES[0]}"


def read_checkpoint(path: Path) -> dict[str, Any]:
    """A checkpoint's metadata with the Python learner's keys.

    For a ``.pt``, the whole torch checkpoint. For a ``.ckpt``, the header mapped onto those
    keys: ``iteration``, ``total_env_steps``, ``config`` (the config's tables), ``provenance``
    (with ``learner``), ``upright_pitch``, ``terrain_levels``, ``dims`` and ``physics_engine``
    ("" where it recorded none).
    """
    if path.suffix != ".ckpt":
        import torch

        state: dict[str, Any] = torch.load(path, map_location="cpu", weights_only=False)
        return state
    header = _rust_header(path)
    try:
        config = tomllib.loads(str(header["config_toml"]))
        return {
            "iteration": int(header["iteration"]),
            "total_env_steps": int(header["total_env_steps"]),
            "config": config,
            "provenance": dict(header.get("provenance") or {}),
            "upright_pitch": header.get("upright_pitch"),
            "terrain_levels": list(header.get("terrain_levels") or []),
            "dims": dict(header.get("dims") or {}),
            "physics_engine": str(header.get("physics_engine") or ""),
        }
    except (KeyError, TypeError, ValueError, tomllib.TOMLDecodeError) as err:
        raise CheckpointError(
            f"{path}: the header is not a unigait-learner checkpoint's: {err}"
        ) from err


def _rust_header(path: Path) -> dict[str, Any]:
    """The JSON header of a Rust learner checkpoint: magic, u64 LE length, then the header."""
    with path.open("rb") as f:
        head = f.read(16)
        if len(head) < 16 or head[:8] != _RUST_MAGIC:
            raise CheckpointError(f"{path}: not a unigait-learner checkpoint (no UGLCKPT1 magic)")
        (length,) = struct.unpack("<Q", head[8:])
        if length > 1 << 30:
            raise CheckpointError(f"{path}: a header of {length} bytes is not plausible")
        text = f.read(length)
    try:
        header = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise CheckpointError(f"{path}: the header is not JSON: {err}") from err
    if not isinstance(header, dict):
        raise CheckpointError(f"{path}: the header is not a JSON object")
    return header


def learner_binary() -> Path:
    """The Rust learner's binary.

    ``$UNIGAIT_LEARNER_BIN``, else the repository's release build, else ``unigait-learner`` on
    ``PATH``.
    """
    env = os.environ.get("UNIGAIT_LEARNER_BIN")
    if env:
        return Path(env)
    built = Path(__file__).resolve().parents[3] / "target" / "release" / "unigait-learner"
    if built.exists():
        return built
    found = shutil.which("unigait-learner")
    if found:
        return Path(found)
    raise CheckpointError(
        "a .ckpt checkpoint is exported by the Rust learner: build it "
        "(cargo build --release --workspace) or set UNIGAIT_LEARNER_BIN"
    )


def export_policy(path: Path, out: Path) -> None:
    """Write checkpoint ``path``'s fused policy to ``out`` as the ONNX the server serves.

    A ``.pt`` is exported with torch and checked against it (a relative difference above 1e-5
    raises); a ``.ckpt`` by ``unigait-learner export``, whose own tests check its graph against
    burn's actor in the server's loader.
    """
    if path.suffix == ".ckpt":
        done = subprocess.run(
            [str(learner_binary()), "export", "--checkpoint", str(path), "--out", str(out)],
            capture_output=True,
            text=True,
            check=False,
        )
        if done.returncode != 0:
            raise CheckpointError(f"{path}: unigait-learner export failed: {done.stderr.strip()}")
        return
    from unigait.export import export_mismatch, export_onnx, load_policy

    policy, dims, engine = load_policy(path)
    export_onnx(policy, out, dims["history_length"], dims["obs_dim"], physics_engine=engine)
    diff = export_mismatch(policy, out)
    if diff > 1e-5:
        raise CheckpointError(f"{path}: the exported graph differs from torch by {diff:.2e}")
