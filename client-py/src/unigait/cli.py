"""Command line: ``python -m unigait {train,export,evaluate,info}``."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shlex
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from unigait.client import (
    Client,
    ConnectionOptions,
    UnigaitError,
    load_connection_options,
    open_session,
)
from unigait.mujoco import cli as mujoco_cli
from unigait.server_process import LocalServer

if TYPE_CHECKING:
    from unigait.live_view import ViewTarget as LiveViewTarget

# Idle OpenMP threads sleep instead of spinning: the learner's torch threads share the cores with
# the simulation server. Set before torch is imported (the commands import it lazily).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


@contextlib.contextmanager
def _servers(addresses: Sequence[str], server_bin: str = "") -> Iterator[list[str]]:
    """The given addresses, or one local server started for the duration."""
    if addresses:
        yield list(addresses)
        return
    server = LocalServer(server_bin or None)
    print(f"no --server given: starting {server.binary}", file=sys.stderr)
    with server:
        print(f"local server listening on {server.address}", file=sys.stderr)
        yield [server.address]


def _add_connection_flags(parser: argparse.ArgumentParser) -> None:
    """``--tls-ca`` and ``--token-file``: reaching servers beyond loopback (TLS + token)."""
    parser.add_argument(
        "--tls-ca",
        metavar="FILE",
        help="PEM CA certificate of the servers: connect with TLS (https://HOST:PORT addresses "
        "use TLS with the system roots without it)",
    )
    parser.add_argument(
        "--token-file",
        metavar="FILE",
        help="file holding the servers' bearer token (default: $UNIGAIT_TOKEN if set)",
    )


def _connection(args: argparse.Namespace) -> ConnectionOptions:
    """Client keyword arguments from ``--tls-ca``, ``--token-file`` and ``$UNIGAIT_TOKEN``."""
    return load_connection_options(args.tls_ca, args.token_file)


#: Flags (each with a value) that say where a stage ran or resumed, not how it trained: left out
#: of the recipe a checkpoint and its model card carry (addresses and credential paths are
#: nobody else's business, and nobody else can use them).
NOT_IN_RECIPE = frozenset(
    {
        "--resume",
        "--server",
        "--ray",
        "--token-file",
        "--tls-ca",
        "--tls-server-name",
        "--server-tls-cert",
        "--server-tls-key",
        "--server-token-file",
    }
)


def _without(argv: Sequence[str], flags: frozenset[str]) -> list[str]:
    """``argv`` less each of ``flags`` with its value (``--flag v`` or ``--flag=v``)."""
    kept: list[str] = []
    skip = False
    for arg in argv:
        if skip:
            skip = False
        elif arg in flags:
            skip = True
        elif arg.split("=", 1)[0] not in flags:
            kept.append(arg)
    return kept


VIEW_FLAGS = frozenset(
    {"--view-envs", "--view-every", "--view-eval-every", "--view-eval-milestone"}
)


def _without_watching(argv: Sequence[str]) -> list[str]:
    """``argv`` less how the run is watched: ``--view`` and its values, ``--tensorboard``."""
    kept: list[str] = []
    in_view = False
    for arg in argv:
        if in_view and not arg.startswith("-"):
            continue
        in_view = arg in ("--view", *VIEW_FLAGS)
        if not in_view and arg != "--tensorboard" and arg.split("=", 1)[0] not in VIEW_FLAGS:
            kept.append(arg)
    return kept


def training_command(argv: Sequence[str]) -> str:
    """The shell line of a command, without where it ran, resumed or got credentials."""
    kept = _without(_without_watching(argv), NOT_IN_RECIPE)
    return shlex.join(["python", "-m", "unigait", *kept])


def _view_target(args: argparse.Namespace) -> LiveViewTarget | None:
    """``--view`` as a target (None without it); ViewError on a malformed one."""
    import dataclasses

    from unigait.live_view import ViewError, parse_view

    if args.view is None:
        return None
    if args.view_envs < 0 or args.view_every < 1 or args.view_eval_every < 0:
        raise ViewError(
            "--view-envs and --view-eval-every must be at least 0, --view-every at least 1"
        )
    from unigait.milestones import milestone

    try:
        milestone(args.view_eval_milestone)
    except KeyError as err:
        raise ViewError(f"--view-eval-milestone: {err.args[0]}") from None
    target = parse_view(args.view)
    return dataclasses.replace(
        target,
        envs=args.view_envs,
        every=args.view_every,
        eval_every=args.view_eval_every,
        eval_milestone=args.view_eval_milestone,
    )


def _train_recipe(args: argparse.Namespace) -> int:
    """``train --recipe``: every stage of a recipe, carrying on where a previous call stopped."""
    from unigait.recipes import RecipeError, describe, load_recipe

    try:
        recipe = load_recipe(args.recipe, list(args.set or []))
    except RecipeError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.dry_run:
        print(describe(recipe))
        return 0
    from unigait.runners.recipe_runner import RecipeRunError, run_recipe

    if args.log_dir is None:
        print("error: a recipe run needs --log-dir (where it resumes from)", file=sys.stderr)
        return 2
    if args.ray is not None or args.resume or args.init_from:
        print("error: --recipe takes no --ray, --resume or --init-from", file=sys.stderr)
        return 2
    from unigait.live_view import ViewError

    try:
        view = _view_target(args)
    except ViewError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    servers = args.server or list(recipe.stages[0].config.env.servers)
    with _servers(servers, recipe.stages[0].config.env.server_bin) as addresses:
        try:
            run_recipe(
                recipe,
                list(args.set or []),
                Path(args.log_dir),
                addresses,
                _connection(args),
                overwrite=args.overwrite,
                adopt=args.adopt_recipe,
                view=view,
                tensorboard=args.tensorboard,
            )
        except (RecipeRunError, ViewError) as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
    return 0


def _view_evaluation(
    view: LiveViewTarget, address: str, connection: ConnectionOptions
) -> Callable[[Any], dict[str, Any]]:
    """The live view's milestone evaluation of a runner's policy (``--view-eval-every``)."""
    from unigait.runners.recipe_runner import evaluate_milestone

    def evaluate(runner: Any) -> dict[str, Any]:
        return evaluate_milestone(
            runner, view.eval_milestone, view.eval_envs, view.eval_seed, address, connection
        )[1]

    return evaluate


def _fresh_log_dir(log_dir: Path, args: argparse.Namespace) -> str | None:
    """Why a run may not write into ``log_dir`` (None: it may).

    A fresh run into a folder that holds another run would mix their logs and write over their
    checkpoints.
    """
    if args.resume or not log_dir.exists() or not any(log_dir.iterdir()):
        return None
    if args.overwrite:
        shutil.rmtree(log_dir)
        return None
    return f"{log_dir} is not empty: give --resume CHECKPOINT, --overwrite or another --log-dir"


def _train(args: argparse.Namespace) -> int:
    if args.recipe:
        return _train_recipe(args)
    if args.dry_run or args.adopt_recipe:
        print("error: --dry-run and --adopt-recipe go with --recipe", file=sys.stderr)
        return 2
    import dataclasses

    from unigait.config import load_config, with_task_setting
    from unigait.live_view import ViewError
    from unigait.runners import CheckpointMismatchError, train

    try:
        view = _view_target(args)
    except ViewError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2

    overrides = list(args.set or [])
    if args.num_envs is not None:
        overrides.append(f"env.num_envs={args.num_envs}")
    if args.iterations is not None:
        overrides.append(f"runner.max_iterations={args.iterations}")
    log_dir_name = args.log_dir or time.strftime("runs/train-%Y%m%d-%H%M%S")
    overrides.append(f"runner.log_dir={json.dumps(log_dir_name)}")
    if args.seed is not None:
        overrides += [f"env.seed={args.seed}", f"runner.seed={args.seed}"]
    if args.quiet:
        overrides.append("runner.quiet=true")
    if args.tensorboard:
        overrides.append("runner.tensorboard=true")
    if args.server:
        overrides.append(f"env.servers={json.dumps(args.server)}")
    cfg = load_config(args.config, overrides)
    if args.quad_only:
        task = with_task_setting(cfg.env.task, "modes.biped_probability", 0.0)
        cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, task=task))
    refusal = _fresh_log_dir(Path(cfg.runner.log_dir), args)
    if refusal:
        print(f"error: {refusal}", file=sys.stderr)
        return 2
    stage = training_command(args.argv)
    if args.ray is not None and view is not None:
        print("error: --view does not go with --ray yet", file=sys.stderr)
        return 2
    if args.ray is not None:  # servers as Ray actors, lost ones replaced: unigait.ray
        from unigait.ray import PoolConfigError, ServerCredentials, train_on_ray

        credentials = ServerCredentials.from_files(
            tls_ca=args.tls_ca,
            token=_connection(args).get("token"),
            server_cert=args.server_tls_cert,
            server_key=args.server_tls_key,
            server_token_file=args.server_token_file,
            tls_server_name=args.tls_server_name,
        )
        try:
            train_on_ray(
                cfg,
                address=args.ray,
                num_servers=args.servers,
                cpus_per_server=args.cpus_per_server,
                resume=args.resume,
                init_from=args.init_from,
                stage=stage,
                credentials=credentials,
                host=None if args.server_host == "node" else args.server_host,
                pool_options={"extra_args": list(args.server_arg or [])},
            )
        except (PermissionError, ConnectionError, PoolConfigError, CheckpointMismatchError) as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
        return 0
    with _servers(cfg.env.servers, cfg.env.server_bin) as addresses:
        connection = _connection(args)
        try:
            train(
                cfg,
                lambda session_cfg: open_session(addresses, session_cfg, **connection),
                resume=args.resume,
                init_from=args.init_from,
                stage=stage,
                servers=", ".join(addresses),
                view=view,
                evaluate=None if view is None else _view_evaluation(view, addresses[0], connection),
            )
        except (CheckpointMismatchError, ViewError) as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
    return 0


def _export(args: argparse.Namespace) -> int:
    from unigait.export import export_mismatch, export_onnx, load_policy

    policy, dims, engine = load_policy(args.checkpoint)
    export_onnx(policy, args.out, dims["history_length"], dims["obs_dim"], physics_engine=engine)
    print(
        f"wrote {args.out}: obs_history f32 [batch, {dims['history_length']}, "
        f"{dims['obs_dim']}] -> actions f32 [batch, {dims['num_actions']}], trained on the "
        f"{engine} engine"
    )
    if args.no_check:
        return 0
    try:
        diff = export_mismatch(policy, args.out)
    except ImportError:
        print("onnxruntime not installed: skipped the check against torch", file=sys.stderr)
        return 0
    print(f"max |onnx - torch| / max(1, max |torch|) on random inputs: {diff:.2e}")
    if diff > 1e-5:
        print(
            "error: the ONNX graph differs from torch by more than 1e-5 (relative)", file=sys.stderr
        )
        return 1
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    policy = Path(args.policy).read_bytes()
    biped = Path(args.biped_policy).read_bytes() if args.biped_policy else b""
    connection = _connection(args)
    with _servers(args.server or []) as addresses, Client(addresses[0], **connection) as client:
        result = client.evaluate(
            policy,
            args.scenario,
            num_envs=args.num_envs,
            seed=args.seed,
            record=args.record is not None,
            record_env=args.record_env,
            biped_policy_onnx=biped,
            task_overrides_toml="\n".join(args.task_set),
        )
    for name in sorted(result.metrics):
        print(f"{name:>40} {result.metrics[name]:.4f}")
    if args.report:
        Path(args.report).write_text(result.report_json)
    if args.record:
        Path(args.record).write_bytes(result.recording_rrd)
    return 0


#: ``ship`` flags that say where this ship read from or wrote to, not what it judged.
_SHIP_PLACES = frozenset({"--run-dir", "--checkpoint", "--out-root", "--lineage"})


def _reproducing_ship(argv: Sequence[str], recipe: str) -> str:
    """The ``ship`` line a model card gives: this one, reading the recipe's fresh run.

    (A fresh run is the recipe's own lineage, so ``--lineage`` goes too.)
    """
    kept = _without(argv, NOT_IN_RECIPE | _SHIP_PLACES)
    return shlex.join(
        ["python", "-m", "unigait", kept[0], "--run-dir", f"runs/{recipe}", *kept[1:]]
    )


def _last_checkpoints(run_dir: Path, count: int, flag: str) -> list[Path] | None:
    """The run's last ``count`` numbered checkpoints, or None (said on stderr) if it has fewer."""
    from unigait.selection import recent_checkpoints
    from unigait.ship import run_folder

    folder = run_folder(run_dir)
    found = [p for _, p in recent_checkpoints(folder, count)]
    if len(found) < count:
        print(
            f"error: {folder} holds {len(found)} numbered checkpoints, {flag} needs {count}",
            file=sys.stderr,
        )
        return None
    return found


def _average(args: argparse.Namespace) -> int:
    from unigait.averaging import AveragingError, describe_average, write_average

    paths: list[Path] = list(args.checkpoints)
    if args.run_dir is not None:
        if paths or args.last <= 0:
            print("error: give checkpoints, or --run-dir with --last N (N > 0)", file=sys.stderr)
            return 2
        found = _last_checkpoints(args.run_dir, args.last, "--last")
        if found is None:
            return 2
        paths = found
    try:
        averaged = write_average(paths, args.out)
    except AveragingError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"{args.out}: {describe_average(averaged['averaged_from'])}")
    return 0


def _ship(args: argparse.Namespace) -> int:
    from unigait.averaging import AveragingError, write_average
    from unigait.milestones import milestone
    from unigait.recipes import RecipeError, load_recipe
    from unigait.selection import describe, select_checkpoint
    from unigait.ship import run_folder, ship

    select_seeds = list(dict.fromkeys(args.select_seed or [2000]))
    if args.select_last > 0 and (args.checkpoint or args.eval_seed in select_seeds):
        print(
            "error: --select-last chooses the checkpoint (no --checkpoint) on seeds other "
            "than --eval-seed",
            file=sys.stderr,
        )
        return 2
    try:
        recipe = load_recipe(args.recipe)
        if args.lineage:
            load_recipe(args.lineage)
        judged_by = args.milestone or recipe.milestone
        if judged_by is None:
            raise RecipeError(f"recipe {recipe.name} names no milestone: give --milestone")
        milestones = [milestone(judged_by), *(milestone(m) for m in args.also or [])]
    except (RecipeError, KeyError) as err:
        print(f"error: {err.args[0] if err.args else err}", file=sys.stderr)
        return 2
    if args.average_last > 0 and (args.checkpoint or args.select_last > 0):
        print(
            "error: --average-last makes the checkpoint: no --checkpoint or --select-last",
            file=sys.stderr,
        )
        return 2
    checkpoint = Path(args.checkpoint) if args.checkpoint else None
    select_envs = args.select_envs or args.num_envs
    selection = None
    with contextlib.ExitStack() as stack, _servers(args.server or []) as addresses:
        if args.average_last > 0:
            found = _last_checkpoints(Path(args.run_dir), args.average_last, "--average-last")
            if found is None:
                return 2
            scratch = Path(stack.enter_context(tempfile.TemporaryDirectory()))
            try:  # the card names the averaged iterations (the checkpoint's averaged_from)
                write_average(found, scratch / found[-1].name)
            except AveragingError as err:
                print(f"error: {err}", file=sys.stderr)
                return 2
            checkpoint = scratch / found[-1].name
        if args.select_last > 0:
            ranked = select_checkpoint(
                run_folder(Path(args.run_dir)),
                milestones[0],
                addresses[0],
                args.select_last,
                select_seeds,
                select_envs,
                by=args.select_by.replace("-", "_"),
                judged_envs=args.num_envs,
            )
            checkpoint = ranked[0].path
            selection = describe(ranked, milestones[0], select_envs)
            print(selection)
        folder = ship(
            Path(args.run_dir),
            args.name,
            recipe.name,
            milestones,
            addresses,
            ship_command=_reproducing_ship(args.argv, recipe.name),
            out_root=Path(args.out_root),
            checkpoint_path=checkpoint,
            eval_seed=args.eval_seed,
            num_envs=args.num_envs,
            selection=selection,
            lineage=args.lineage,
        )
    print((folder / "MODEL_CARD.md").read_text())
    print(f"shipped to {folder}")
    return 0


def _compare(args: argparse.Namespace) -> int:
    import torch

    from unigait.compare import run_ours, run_rsl_rl, write

    torch.set_num_threads(1)
    runs: dict[str, list[dict[str, float]]] = {}
    with _servers(args.server or []) as addresses:
        for name in args.learners:
            print(f"training with {name}: {args.num_envs} envs, {args.iterations} iterations")
            if name == "ours":
                runs[name] = run_ours(addresses[0], args.num_envs, args.iterations, args.seed)
            else:
                runs[name] = run_rsl_rl(
                    addresses[0],
                    args.num_envs,
                    args.iterations,
                    args.seed,
                    obs_normalization=name == "rsl_rl_normalized",
                )
    write(Path(args.out), runs)
    for name, rows in runs.items():
        last = rows[-10:]
        mean = sum(r["tracking"] for r in last) / max(len(last), 1)
        print(f"{name:>18}: quad tracking per step over the last {len(last)} iterations {mean:.4f}")
    print(f"wrote {args.out}/compare.csv and {args.out}/compare.png")
    return 0


def _info(args: argparse.Namespace) -> int:
    connection = _connection(args)
    with _servers(args.server or []) as addresses:
        for address in addresses:
            with Client(address, **connection) as client:
                print(address, client.server_info())
    return 0


def _checks(args: argparse.Namespace) -> int:
    from unigait.milestone_log import MilestoneLogError, milestone_tables, read_milestone_log

    try:
        print(milestone_tables(read_milestone_log(Path(args.log_dir))), end="")
    except MilestoneLogError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


def _pass_chance(args: argparse.Namespace) -> int:
    from unigait.milestones import milestone
    from unigait.pass_chance import ReportError, chance_table, evals_by_seed

    try:
        judged = milestone(args.milestone)
        by_seed = evals_by_seed([Path(r) for r in args.reports])
        draw = {s: judged.envs_for(s, args.num_envs) for s in judged.scenarios}
        print(chance_table(judged, by_seed, draw), end="")
    except (KeyError, ReportError) as err:
        print(f"error: {err.args[0] if err.args else err}", file=sys.stderr)
        return 2
    return 0


def _trials(args: argparse.Namespace) -> int:
    from unigait.trial_table import TrialTableError, friction_tables, read_trials, trial_tables

    try:
        trials = read_trials(Path(args.report))
        if args.by_friction:
            print(friction_tables(trials), end="")
        else:
            print(trial_tables(trials, everything=args.all), end="")
    except TrialTableError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every sub-command."""
    p = argparse.ArgumentParser(prog="unigait", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    t = sub.add_parser("train", help="PPO + concurrent estimator against unigait server(s)")
    t.add_argument("--config", help="TOML file with [env], [policy], [ppo], [estimator], [runner]")
    t.add_argument(
        "--set",
        action="append",
        metavar="SECTION.KEY=VALUE",
        help="override a config value (TOML syntax), repeatable",
    )
    t.add_argument(
        "--server",
        action="append",
        metavar="HOST:PORT",
        help="server address, repeatable (shards the envs); none: start a local one",
    )
    _add_connection_flags(t)
    t.add_argument(
        "--ray",
        nargs="?",
        const="",
        metavar="ADDRESS",
        help="start the servers as Ray actors (cluster ADDRESS, e.g. auto; none: ray.init())",
    )
    t.add_argument("--servers", type=int, default=1, help="with --ray: server actors")
    t.add_argument("--cpus-per-server", type=int, default=1, help="with --ray: CPUs per actor")
    t.add_argument(
        "--server-host",
        default="127.0.0.1",
        metavar="ADDR",
        help="with --ray: address the servers bind; 'node': each node's IP (beyond loopback: "
        "needs --server-tls-cert, --server-tls-key and a token)",
    )
    t.add_argument(
        "--server-tls-cert",
        metavar="PATH",
        help="with --ray: the servers' TLS certificate, a path on every node (the learner "
        "verifies it with --tls-ca)",
    )
    t.add_argument("--server-tls-key", metavar="PATH", help="with --ray: its key, on every node")
    t.add_argument(
        "--server-token-file",
        metavar="PATH",
        help="with --ray: the servers' token file, a path on every node (default: the "
        "learner's token from --token-file / $UNIGAIT_TOKEN goes to the servers with the actors)",
    )
    t.add_argument(
        "--tls-server-name",
        metavar="NAME",
        help="with --ray: check the servers' certificate against NAME, not their IP",
    )
    t.add_argument(
        "--server-arg",
        action="append",
        metavar="FLAG",
        help="with --ray: one more `serve` flag for every server, written with =, e.g. "
        "--server-arg=--max-total-envs=8192 (how a pod's memory limit bounds its server)",
    )
    t.add_argument("--num-envs", type=int)
    t.add_argument("--iterations", type=int, help="total iterations (runner.max_iterations)")
    t.add_argument("--log-dir", help="output folder (default: runs/train-DATE-TIME)")
    t.add_argument("--seed", type=int)
    t.add_argument("--resume", metavar="CHECKPOINT", help="continue from a model_*.pt")
    t.add_argument("--quad-only", action="store_true", help="biped_probability = 0")
    t.add_argument(
        "--recipe",
        metavar="NAME|FILE",
        help="train every stage of a recipe (a packaged name such as unified_flat, or a .toml "
        "file); the same command again carries on where it stopped. --set applies to every stage",
    )
    t.add_argument(
        "--dry-run", action="store_true", help="with --recipe: print the resolved stages and exit"
    )
    t.add_argument(
        "--adopt-recipe",
        action="store_true",
        help="with --recipe: go on in a log directory whose run started from another recipe text",
    )
    t.add_argument(
        "--overwrite",
        action="store_true",
        help="delete what --log-dir holds first (a fresh run refuses a non-empty one otherwise)",
    )
    t.add_argument(
        "--init-from",
        metavar="CHECKPOINT",
        help="staged training: take the networks (not the optimiser or counters) of a model_*.pt",
    )
    t.add_argument("--quiet", action="store_true", help="one line per iteration")
    t.add_argument(
        "--view",
        nargs="+",
        metavar="ARG",
        help="stream the run to rerun: serve [[HOST:]PORT] (loopback 127.0.0.1:9876 by default; "
        "join with rerun --connect URL), connect URL (a running viewer), or save PATH.rrd",
    )
    t.add_argument(
        "--view-envs",
        type=int,
        default=4,
        metavar="K",
        help="with --view: training envs whose robots are drawn (from the server; 0: curves only)",
    )
    t.add_argument(
        "--view-every",
        type=int,
        default=10,
        metavar="N",
        help="with --view: draw them during every N-th iteration's rollout",
    )
    t.add_argument(
        "--view-eval-every",
        type=int,
        default=0,
        metavar="M",
        help="with --view: evaluate the policy on a milestone every M iterations, on a fixed "
        "seed (2000, the recipes' validation seed), into the view (0: never)",
    )
    t.add_argument(
        "--view-eval-milestone",
        default="M1",
        metavar="NAME",
        help="with --view-eval-every: the milestone (a recipe stage's own milestone first)",
    )
    t.add_argument(
        "--tensorboard",
        action="store_true",
        help="also write TensorBoard events beside progress.csv (runner.tensorboard)",
    )
    t.set_defaults(func=_train)

    e = sub.add_parser("export", help="fused estimator + actor to ONNX")
    e.add_argument("--checkpoint", required=True)
    e.add_argument("--out", required=True)
    e.add_argument("--no-check", action="store_true", help="skip the onnxruntime comparison")
    e.set_defaults(func=_export)

    v = sub.add_parser("evaluate", help="run the server's Evaluate on an ONNX policy")
    v.add_argument("--policy", required=True, help="ONNX file")
    v.add_argument("--scenario", required=True, help="e.g. stairs_up_quad")
    v.add_argument("--server", action="append", metavar="HOST:PORT")
    _add_connection_flags(v)
    v.add_argument("--num-envs", type=int, default=0)
    v.add_argument("--seed", type=int, default=0)
    v.add_argument("--biped-policy", help="second ONNX policy for the two-policy baseline")
    v.add_argument(
        "--record", metavar="OUT.rrd", help="write a rerun recording (trial 0 unless --record-env)"
    )
    v.add_argument(
        "--record-env",
        type=int,
        metavar="K",
        help="the trial the recording follows (default 0), numbered across the scenario's cases "
        "as the report lists them: a traversal's forward trials, then its backward ones",
    )
    v.add_argument("--report", metavar="OUT.json", help="write the full JSON report")
    v.add_argument(
        "--set",
        dest="task_set",
        action="append",
        default=[],
        metavar="TOML",
        help="a task config line to override (repeatable), e.g. 'physics.engine = \"articulated\"'",
    )
    v.set_defaults(func=_evaluate)

    s = sub.add_parser("ship", help="export, evaluate and document a trained policy")
    s.add_argument(
        "--run-dir",
        required=True,
        help="training output (model_latest.pt, curves), or a recipe run's (its last stage)",
    )
    s.add_argument("--name", required=True, help="folder under --out-root")
    s.add_argument(
        "--recipe", required=True, help="the recipe that reproduces it (names its milestone)"
    )
    s.add_argument("--milestone", help="judge it by this milestone instead of the recipe's")
    s.add_argument(
        "--also",
        action="append",
        metavar="MILESTONE",
        help="also report where it stands against this milestone (repeatable), e.g. M2+",
    )
    s.add_argument(
        "--lineage",
        metavar="RECIPE",
        help="the recipe recording how this checkpoint was made, when not --recipe",
    )
    s.add_argument("--checkpoint", help="a model_*.pt instead of model_latest.pt")
    s.add_argument("--out-root", default="assets/policies")
    s.add_argument("--server", action="append", metavar="HOST:PORT")
    s.add_argument("--eval-seed", type=int, default=1000, help="a seed training never used")
    s.add_argument("--num-envs", type=int, default=64)
    s.add_argument(
        "--select-last",
        type=int,
        default=0,
        metavar="N",
        help="ship the best of the run's last N checkpoints, judged on --select-seed",
    )
    s.add_argument(
        "--select-seed",
        type=int,
        action="append",
        metavar="SEED",
        help="validation seed of --select-last (default 2000); repeat it to judge each candidate "
        "on several, ranked first by the seeds on which it meets the milestone",
    )
    s.add_argument(
        "--select-envs",
        type=int,
        default=None,
        help="envs per scenario for --select-last (default: --num-envs); more envs make a "
        "success rate's noise smaller, so the best-looking candidate is less often a lucky one",
    )
    s.add_argument(
        "--select-by",
        choices=["criteria", "pass-chance"],
        default="criteria",
        help="rank --select-last's candidates by the milestone's criteria met on each seed "
        "(scenarios at the milestone's own size), or by the estimated chance of meeting it on "
        "one unseen draw, every scenario at --select-envs (docs: evaluation)",
    )
    s.add_argument(
        "--average-last",
        type=int,
        default=0,
        metavar="N",
        help="ship the mean of the weights of the run's last N checkpoints (decision 0044): a "
        "run under an adaptive learning rate swings between checkpoints, their mean less",
    )
    s.set_defaults(func=_ship)

    a = sub.add_parser(
        "average", help="a checkpoint whose networks are the mean of several checkpoints'"
    )
    a.add_argument("checkpoints", nargs="*", type=Path, help="model_*.pt files, oldest first")
    a.add_argument("--run-dir", type=Path, help="average this run's last --last checkpoints")
    a.add_argument("--last", type=int, default=0, metavar="N")
    a.add_argument("--out", type=Path, required=True, help="the averaged model_*.pt")
    a.set_defaults(func=_average)

    c = sub.add_parser("compare-rsl-rl", help="our learner vs rsl_rl's runner, quad on flat")
    c.add_argument("--server", action="append", metavar="HOST:PORT")
    c.add_argument("--num-envs", type=int, default=256)
    c.add_argument("--iterations", type=int, default=100)
    c.add_argument("--seed", type=int, default=1)
    c.add_argument(
        "--learners",
        nargs="+",
        default=["ours", "rsl_rl"],
        choices=["ours", "rsl_rl", "rsl_rl_normalized"],
    )
    c.add_argument("--out", default="runs/compare")
    c.set_defaults(func=_compare)

    i = sub.add_parser("info", help="print server info")
    i.add_argument("--server", action="append", metavar="HOST:PORT")
    _add_connection_flags(i)
    i.set_defaults(func=_info)

    k = sub.add_parser(
        "checks", help="a recipe run's milestone checks, one Markdown table per milestone"
    )
    k.add_argument("log_dir", help="a run's --log-dir, or one stage's folder in it")
    k.set_defaults(func=_checks)

    r = sub.add_parser(
        "trials", help="a traversal report's trials: where each ended, one table per scenario"
    )
    r.add_argument("report", help="a JSON report of evaluate --report (or ship's)")
    r.add_argument("--all", action="store_true", help="every trial, not only those that failed")
    r.add_argument(
        "--by-friction",
        action="store_true",
        help="each case's trials crossed / run by the friction of their contacts",
    )
    r.set_defaults(func=_trials)

    c = sub.add_parser(
        "pass-chance",
        help="the chance that one unseen draw meets a milestone, from reports with many trials",
    )
    c.add_argument("reports", nargs="+", help="evaluate --report files: every scenario, each seed")
    c.add_argument("--milestone", default="M3")
    c.add_argument(
        "--num-envs",
        type=int,
        default=64,
        help="the judged draw's envs for scenarios the milestone does not size (ship's default)",
    )
    c.set_defaults(func=_pass_chance)

    mujoco_cli.register(sub)  # sim2sim, crosscheck, mujoco-bench: MuJoCo imported on use
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m unigait`` and the ``unigait`` script."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    args.argv = argv
    try:
        return int(args.func(args))
    except UnigaitError as err:
        print(f"error: server said {err}", file=sys.stderr)
        return 2
