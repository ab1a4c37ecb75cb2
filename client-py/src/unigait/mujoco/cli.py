"""``python -m unigait sim2sim``, ``crosscheck`` and ``mujoco-bench``.

:func:`register` adds the sub-commands to the package's parser; MuJoCo and onnxruntime are
imported only when one of them runs (they come with the ``mujoco`` extra).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

SIM2SIM_SCENARIOS = (
    "tracking_quad",
    "tracking_biped",
    "transition_biped_to_quad",
    "transition_quad_to_biped",
    "flat_quad",
    "flat_biped",
)
"""The scenarios of :mod:`unigait.mujoco.sim2sim` (listed here so the parser needs no MuJoCo)."""


def _sim2sim(args: argparse.Namespace) -> int:
    import dataclasses

    from unigait.mujoco.observation import TaskSettings
    from unigait.mujoco.sim2sim import evaluate

    settings = dataclasses.replace(TaskSettings(), noise_level=args.noise_level)
    metrics = evaluate(
        args.policy, args.scenario, args.num_envs, args.seed, settings, record=args.record
    )
    for name in sorted(metrics):
        print(f"{name:>40} {metrics[name]:.4f}")
    if args.report:
        report = {"scenario": args.scenario, "simulator": "mujoco", "metrics": metrics}
        Path(args.report).write_text(json.dumps(report, indent=2))
    return 0


def _crosscheck(args: argparse.Namespace) -> int:
    from unigait.mujoco.crosscheck import compare, find_crosscheck_binary, format_table

    try:
        binary = Path(args.binary) if args.binary else find_crosscheck_binary()
    except FileNotFoundError as e:
        print(f"error: {e} (or pass --binary)", file=sys.stderr)
        return 1
    if not binary.is_file():
        print(
            f"error: {binary} not found: `cargo build --release -p unigait-crosscheck`",
            file=sys.stderr,
        )
        return 1
    print(format_table(compare(binary, args.scenario or None, args.armature)))
    return 0


def _bench(args: argparse.Namespace) -> int:
    from unigait.mujoco.bench import main

    return main(args.envs, args.steps, args.solver, Path(args.server) if args.server else None)


def register(subparsers: Any) -> None:
    """Add the ``sim2sim`` and ``crosscheck`` sub-commands to ``subparsers``.

    Args:
        subparsers: What ``ArgumentParser.add_subparsers`` returned.
    """
    s = subparsers.add_parser(
        "sim2sim", help="run an ONNX policy in MuJoCo on a flat-ground evaluation scenario"
    )
    s.add_argument("--policy", required=True, help="ONNX file (obs_history [B,3,53] -> [B,12])")
    s.add_argument("--scenario", required=True, choices=SIM2SIM_SCENARIOS)
    s.add_argument("--num-envs", type=int, default=0, help="trials (0 = the scenario's default)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument(
        "--noise-level", type=float, default=0.0, help="observation noise level (server: 1.0)"
    )
    s.add_argument("--report", metavar="OUT.json", help="write the metrics as JSON")
    s.add_argument("--record", metavar="OUT.rrd", help="write a rerun recording of env 0")
    s.set_defaults(func=_sim2sim)

    c = subparsers.add_parser(
        "crosscheck", help="physics cross-checks: our simulator against MuJoCo, side by side"
    )
    c.add_argument(
        "--binary",
        help="the cross-check driver (default: $UNIGAIT_CROSSCHECK_BIN, else "
        "unigait-crosscheck on PATH)",
    )
    c.add_argument("--scenario", action="append", help="scenario name, repeatable (default all)")
    c.add_argument(
        "--armature", type=float, help="joint armature for both engines (default nominal 0.02)"
    )
    c.set_defaults(func=_crosscheck)

    b = subparsers.add_parser(
        "mujoco-bench",
        help="MuJoCo's side of the simulation benchmark (one JSON line per solver setting)",
    )
    b.add_argument("--envs", type=int, default=512)
    b.add_argument("--steps", type=int, default=300, help="policy steps timed (after 20)")
    b.add_argument(
        "--solver",
        nargs="+",
        default=["default", "playground"],
        choices=["default", "playground"],
        help="solver settings: the cross-check model's, MuJoCo Playground's training settings",
    )
    b.add_argument(
        "--server",
        metavar="UNIGAIT_SERVER",
        help="also run this unigait-server's bench (with and without joints) and print both "
        "engines' stages side by side, in microseconds per robot physics step",
    )
    b.set_defaults(func=_bench)
