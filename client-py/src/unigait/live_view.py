"""A live view of a training run in rerun, and TensorBoard logging beside the CSV.

``python -m unigait train ... --view serve|connect URL|save PATH`` streams every scalar the run
logs (the ``progress.csv`` columns) as rerun time series ``curves/<name>`` on the ``iteration``
timeline, with a blueprint of its own: tabs of a few panels each (progress, reward terms per
mode, optimiser, throughput, evaluation, and every other scalar). Text events (``events``) say
where a run started, resumed or a recipe stage began.

A resumed run continues the same recording: its recording id is derived from the run's folder,
so a viewer that holds the first part (served, connected or a saved file opened beside the
resumed one) shows one set of curves, with an ``events`` line at the iteration it resumed from.
Appending (rather than a new recording) keeps the curve a user watches whole across restarts,
which is the point of watching a days-long run.
"""

from __future__ import annotations

import datetime
import math
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    import rerun as rr

#: Root of the curves: ``curves/<scalar name>``.
CURVES = "curves"
#: Text events (run start, resume, recipe stages, evaluations).
EVENTS = "events"
#: The timeline of the curves.
TIMELINE = "iteration"
#: Policy steps of the run (the drawn envs' poses; the curves are on ``iteration`` only).
STEP_TIMELINE = "step"
#: Parent of the drawn envs, as the server's recordings draw their other envs:
#: ``world/envs/<slot>/robot/<body>`` (and the static shapes at ``.../<body>/geom<k>``).
ENVS = "world/envs"
#: Where ``--view serve`` listens by default: loopback, the server's ``record --serve`` port.
DEFAULT_SERVE = "127.0.0.1:9876"
#: Longest a curve's new row waits before it is sent (rows of a few iterations share a chunk).
BATCH_S = 10.0
#: What the serving process buffers for late viewers (oldest dropped beyond it).
SERVE_MEMORY_LIMIT = "1GiB"

ViewKind = Literal["serve", "connect", "save"]


class ViewError(ValueError):
    """A ``--view`` that cannot be set up (the message says what to give instead)."""


@dataclass(frozen=True)
class ViewTarget:
    """Where the live view goes.

    Attributes:
        kind: ``serve`` (a rerun server the learner starts; viewers join its URL), ``connect``
            (a running viewer or server at ``where``) or ``save`` (an ``.rrd`` file).
        where: ``serve``: ``[HOST:]PORT`` to bind (default loopback); ``connect``: the URL;
            ``save``: the file.
        envs: Training envs drawn (their robots, from the server); 0: curves only.
        every: Draw them during every this many-th iteration's rollout.
        eval_every: Evaluate the policy every this many iterations (0: never; a recipe stage
            with a milestone logs its own checks to the view in any case).
        eval_milestone: The milestone evaluated (a recipe stage's own milestone first).
        eval_envs: Envs per scenario.
        eval_seed: The evaluations' fixed seed (the recipes' validation seed).
    """

    kind: ViewKind
    where: str
    envs: int = 4
    every: int = 10
    eval_every: int = 0
    eval_milestone: str = "M1"
    eval_envs: int = 64
    eval_seed: int = 2000


def parse_view(values: Sequence[str]) -> ViewTarget:
    """``--view`` arguments as a target: ``serve [[HOST:]PORT]``, ``connect URL``, ``save PATH``.

    Raises:
        ViewError: Another form.
    """
    if not values:
        raise ViewError("--view takes serve [[HOST:]PORT], connect URL or save PATH")
    kind, rest = values[0], list(values[1:])
    if kind == "serve" and len(rest) <= 1:
        where = rest[0] if rest else DEFAULT_SERVE
        _split_bind(where)
        return ViewTarget("serve", where)
    if kind == "connect" and len(rest) == 1:
        return ViewTarget("connect", rest[0])
    if kind == "save" and len(rest) == 1:
        return ViewTarget("save", rest[0])
    raise ViewError(
        f"--view {' '.join(values)}: give serve [[HOST:]PORT], connect URL (e.g. "
        "rerun+http://127.0.0.1:9876/proxy) or save PATH.rrd"
    )


def _split_bind(where: str) -> tuple[str, int]:
    host, _, port = where.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        raise ViewError(f"--view serve {where}: the port must be a number (0-65535)") from None
    if not 0 <= number <= 65535:
        raise ViewError(f"--view serve {where}: the port must be 0-65535")
    return host or "127.0.0.1", number


def recording_id(run_dir: Path) -> str:
    """The recording id of a run folder: the same on every resume, so the curves continue."""
    return str(uuid.uuid5(uuid.NAMESPACE_URL, f"unigait-train:{run_dir.resolve()}"))


def _free_path(path: Path) -> Path:
    """``path``, or ``<stem>.<k><suffix>`` beside it when it exists (a resumed run's part)."""
    k = 1
    free = path
    while free.exists():
        k += 1
        free = path.with_name(f"{path.stem}.{k}{path.suffix}")
    return free


def _rerun_cli() -> str:
    beside = Path(sys.executable).with_name("rerun")
    found = str(beside) if beside.is_file() else shutil.which("rerun")
    if not found:
        raise ViewError("--view serve needs the rerun CLI: pip install 'unigait[viz]'")
    return found


class _ServeProcess:
    """``rerun --serve-grpc`` bound where asked (loopback by default), for the run's lifetime.

    The Python SDK's own ``serve_grpc`` binds every interface; the CLI takes ``--bind``, so the
    default view is not reachable from another machine unless the user says so.
    """

    def __init__(self, where: str) -> None:
        host, port = _split_bind(where)
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
            try:
                probe.bind((host, port))
            except OSError as err:
                raise ViewError(
                    f"--view serve {where}: cannot listen there ({err}); give another port"
                ) from None
            port = probe.getsockname()[1]  # port 0: a free one
        self.url = f"rerun+http://{host}:{port}/proxy"
        self.proc = subprocess.Popen(
            [
                _rerun_cli(),
                "--serve-grpc",
                "--bind",
                host,
                "--port",
                str(port),
                "--server-memory-limit",
                SERVE_MEMORY_LIMIT,
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            # `rerun` is a Python launcher that starts the viewer binary as its child: signal
            # the whole group, or the binary outlives the run.
            start_new_session=True,
        )
        deadline = time.monotonic() + 20.0
        while True:
            try:
                with socket.create_connection(
                    ("127.0.0.1" if host in ("0.0.0.0", "::") else host, port), 0.2
                ):
                    break
            except OSError:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    self.close()
                    raise ViewError(f"--view serve {where}: rerun's server did not start") from None
                time.sleep(0.05)
        if host not in ("127.0.0.1", "localhost", "::1"):
            print(
                f"warning: the live view listens on {host}: whoever reaches it sees the run",
                file=sys.stderr,
            )

    def close(self) -> None:
        group = self.proc.pid  # its own session: the group id is its pid
        try:
            os.killpg(group, signal.SIGTERM)
        except ProcessLookupError:
            return  # the launcher and the binary are gone
        deadline = time.monotonic() + 5.0
        while _group_alive(group) and time.monotonic() < deadline:
            self.proc.poll()  # reap the launcher, so its pid leaves the group
            time.sleep(0.05)
        if _group_alive(group):
            os.killpg(group, signal.SIGKILL)
        self.proc.wait()


def _group_alive(group: int) -> bool:
    """Whether any process of process group ``group`` is still there."""
    try:
        os.killpg(group, 0)
    except ProcessLookupError:
        return False
    return True


def _terms_by_mode(terms: Sequence[str]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {"quad": [], "biped": [], "both modes": []}
    for t in terms:
        key = (
            "quad" if t.startswith("quad_") else "biped" if t.startswith("biped_") else "both modes"
        )
        out[key].append(t)
    return out


def curve(name: str) -> str:
    """The entity path of scalar ``name`` (its ``/`` keep their meaning)."""
    import rerun as rr

    return "/".join([CURVES, *(rr.escape_entity_path_part(p) for p in name.split("/"))])


#: Panels of the first tabs: (tab, panel title, scalar names, prefixes ending in ``/`` (one
#: level below them) or patterns whose ``*`` stands for one level).
PANELS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("progress", "mean episode reward", ("mean_episode_reward",)),
    ("progress", "mean reward per step", ("mean_step_reward",)),
    ("progress", "mean episode length (steps)", ("mean_episode_length",)),
    ("progress", "terrain level (mean, per type, per mode)", ("terrain_level", "terrain_level/")),
    ("progress", "terrain level per type, four legs", ("terrain_level/*/quad",)),
    ("progress", "terrain level per type, two legs", ("terrain_level/*/biped",)),
    ("progress", "upright indicator threshold (rad)", ("curriculum/upright_pitch",)),
    ("progress", "biped mode: share and pose", ("biped_share", "biped_pose/")),
    ("optimiser", "learning rate", ("learning_rate",)),
    ("optimiser", "KL", ("kl",)),
    ("optimiser", "action noise (std)", ("action_std",)),
    ("optimiser", "losses", ("value_loss", "surrogate_loss")),
    ("optimiser", "estimator MSE", ("estimator_loss",)),
    ("optimiser", "entropy", ("entropy",)),
    ("throughput", "env steps/s", ("env_steps_per_s",)),
    ("throughput", "time share: simulation / inference / update", ("time_share/",)),
    ("throughput", "iteration time (s)", ("iteration_time_s",)),
)


def _matches(name: str, keys: Sequence[str]) -> bool:
    """Whether ``name`` is one of ``keys``: a name, a prefix or a pattern.

    A prefix ``a/`` takes ``a/b``, not ``a/b/c``; a pattern ``a/*/c`` takes ``a/b/c``.
    """
    for key in keys:
        if "*" in key:
            if re.fullmatch(re.escape(key).replace(r"\*", "[^/]+"), name):
                return True
        elif key.endswith("/"):
            if name.startswith(key) and "/" not in name[len(key) :]:
                return True
        elif name == key:
            return True
    return False


def blueprint(
    names: Sequence[str],
    reward_terms: Sequence[str],
    robots: int = 0,
    eval_panels: Sequence[tuple[str, str]] = (),
) -> Any:
    """The view's layout: a tab per theme, each a grid of a few time series panels.

    Args:
        names: The scalar names the run logs.
        reward_terms: The session's reward terms (``episode_reward/<term>``), split by mode.
        robots: Envs the view draws (a 3D tab when non-zero).
        eval_panels: (title, scalar) of each milestone check evaluated.
    """
    import rerun.blueprint as rrb

    present = set(names)
    placed: set[str] = set()
    tabs: dict[str, list[Any]] = {}

    def panel(tab: str, title: str, series: list[str]) -> None:
        series = [s for s in series if s in present]
        if series:
            placed.update(series)
            tabs.setdefault(tab, []).append(
                rrb.TimeSeriesView(name=title, origin="/", contents=[curve(s) for s in series])
            )

    for tab, title, keys in PANELS:
        panel(tab, title, [n for n in names if _matches(n, keys)])
    for mode, terms in _terms_by_mode(reward_terms).items():
        panel(
            "reward terms",
            f"{mode} terms (per s of episode)",
            [f"episode_reward/{t}" for t in terms],
        )
    panel("evaluation", "milestone criteria met", ["eval/criteria_met"])
    for title, name in eval_panels:
        panel("evaluation", title, [name])
    for name in names:  # every other scalar, one panel each (the unchecked eval metrics: none)
        if name not in placed and name != "iteration" and not name.startswith("eval/"):
            panel("more", name, [name])
    curves = rrb.Tabs(
        *(rrb.Grid(*panels, name=tab) for tab, panels in tabs.items()),
        rrb.TextLogView(name="events", origin=f"/{EVENTS}"),
    )
    if not robots:
        return rrb.Blueprint(
            curves, rrb.TimePanel(timeline=TIMELINE, state="collapsed"), collapse_panels=True
        )
    # The drawn envs beside the curves: one view per env, its camera on the robot's base.
    follow = [
        rrb.Spatial3DView(
            name=f"env slot {k}",
            origin="/world",
            contents=[f"/{ENVS}/{k}/**"],
            eye_controls=rrb.EyeControls3D(tracking_entity=f"/{ENVS}/{k}/robot/base"),
        )
        for k in range(robots)
    ]
    robot_views = rrb.Tabs(
        rrb.Grid(*follow, name="robots"),
        rrb.Spatial3DView(name="all drawn envs", origin="/world"),
    )
    return rrb.Blueprint(
        rrb.Horizontal(robot_views, curves, column_shares=[2, 3]),
        rrb.TimePanel(timeline=TIMELINE, state="collapsed"),
        collapse_panels=True,
    )


class LiveView:
    """Streams a run's scalars to rerun, one row per iteration.

    Args:
        target: Where the view goes.
        run_dir: The run's folder (its recording id; a resumed run continues the recording).
        name: Recording name shown in the viewer.
        reward_terms: The session's reward terms (the blueprint groups them by mode).
    """

    def __init__(
        self, target: ViewTarget, run_dir: Path, name: str, reward_terms: Sequence[str] = ()
    ) -> None:
        try:
            import rerun as rr
        except ImportError:
            raise ViewError("--view needs rerun: pip install 'unigait[viz]'") from None
        self.rr = rr
        self.target = target
        self.reward_terms = list(reward_terms)
        self.names: list[str] = []
        #: Envs drawn (a 3D tab when non-zero; set by :class:`RobotDrawer`).
        self.robots = 0
        #: (title, scalar) of each evaluated milestone check: the evaluation tab.
        self.eval_panels: list[tuple[str, str]] = []
        #: Added to the runner's iteration on the timeline (a recipe's later stages).
        self.offset = 0
        self.url = ""
        self._server: _ServeProcess | None = None
        # Rows wait up to BATCH_S in the batcher: a chunk holds a few iterations of a curve
        # instead of one (measured: 100 scalars cost 123 kB per iteration flushed one by one,
        # 15 kB in chunks of 10), at the price of curves reaching the viewer that much later.
        batching = rr.ChunkBatcherConfig(flush_tick=datetime.timedelta(seconds=BATCH_S))
        self.rec: rr.RecordingStream = rr.RecordingStream(
            "unigait", recording_id=recording_id(run_dir), batcher_config=batching
        )
        if target.kind == "save":
            path = _free_path(Path(target.where))
            if str(path) != target.where:
                print(
                    f"live view: {target.where} exists; writing this part to {path} (the same "
                    f"recording: open both, rerun {target.where} {path})",
                    file=sys.stderr,
                )
            path.parent.mkdir(parents=True, exist_ok=True)
            self.rec.save(str(path))
            self.url = str(path)
        else:
            if target.kind == "serve":
                self._server = _ServeProcess(target.where)
                self.url = self._server.url
            else:
                self.url = target.where
            self.rec.connect_grpc(self.url)
        self.rec.send_recording_name(name)
        if target.kind != "save":
            print(f"live view: rerun --connect {self.url}", file=sys.stderr, flush=True)

    def event(self, iteration: int, text: str) -> None:
        """A line in the events log at ``iteration`` (the runner's)."""
        self.rec.set_time(TIMELINE, sequence=self.offset + iteration)
        self.rec.log(EVENTS, self.rr.TextLog(text))

    def log(self, scalars: Mapping[str, float]) -> None:
        """Every scalar of one iteration (``scalars["iteration"]`` places them)."""
        rr, rec = self.rr, self.rec
        new = [n for n in scalars if n not in self.names]
        if new:  # the first iteration, or a scalar that appears later (an evaluation)
            self.names += new
            self.send_blueprint()
        rec.set_time(TIMELINE, sequence=self.offset + int(scalars["iteration"]))
        for name, value in scalars.items():
            rec.log(curve(name), rr.Scalars(float(value) if math.isfinite(value) else math.nan))

    def log_evaluation(self, record: Mapping[str, Any]) -> None:
        """A milestone evaluation (``evaluate_milestone``'s record) at its iteration.

        Scalars ``eval/<scenario>/<metric>`` for every metric, ``eval/criteria_met`` and
        ``eval/margin``; the evaluation tab shows the criteria met and each checked metric.
        """
        from unigait.milestones import milestone

        target = milestone(str(record["milestone"]))
        scalars = {"iteration": float(record["iteration"])}
        scalars["eval/criteria_met"] = float(record["criteria_met"])
        scalars["eval/margin"] = float(record["margin"])
        for scenario, metrics in record["evals"].items():
            for metric, value in metrics.items():
                scalars[f"eval/{scenario}/{metric}"] = float(value)
        for check in target.checks:
            title = f"{check.label} ({check.metric} {check.op} {check.bound:g})"
            panel = (title, f"eval/{check.scenario}/{check.metric}")
            if panel not in self.eval_panels:
                self.eval_panels.append(panel)
        met, total = record["criteria_met"], record["criteria"]
        verdict = f"{target.name}: {met}/{total} criteria met on seed {record['seed']}"
        unmet = record.get("unmet") or []
        if unmet:  # what is missing, with its figures, as the run's log prints it
            verdict += "; unmet: " + "; ".join(str(u) for u in unmet)
        self.event(int(record["iteration"]), verdict)
        self.log(scalars)

    def send_blueprint(self) -> None:
        """(Re)send the layout (new scalars, drawn envs)."""
        bp = blueprint(self.names, self.reward_terms, self.robots, self.eval_panels)
        self.rec.send_blueprint(bp, make_active=True)

    def close(self) -> None:
        """Flush; stop serving (a served view ends with the run)."""
        self.rec.flush()
        self.rec.disconnect()
        if self._server is not None:
            self._server.close()


class RobotDrawer:
    """Draws K training envs in a live view, from the poses the server returns.

    The envs are drawn at random at the start (a fixed seed) and each is re-drawn when its
    episode ends (a fall or a time-out), so the view keeps showing robots mid-episode. The
    robot's shapes come from the server once (``Spec.robot_drawing_rrd``: the recordings'
    drawing), re-rooted at ``world/envs/<slot>/robot``; every step of a drawn iteration the
    server returns the bodies' poses of the chosen envs (``StepRequest.draw_envs``), sent to the
    view in one batch per body at the end of the rollout.

    Args:
        view: The live view.
        spec: The session's spec (with the robot's drawing).
        count: Envs drawn (K).
        every: Draw every this many iterations.
        seed: The choice's seed.
    """

    def __init__(self, view: LiveView, spec: Any, count: int, every: int, seed: int) -> None:
        import numpy as np

        self.np = np
        self.view = view
        self.every = max(1, every)
        self.bodies = list(spec.body_names)
        self.rng = np.random.default_rng(seed)
        n = int(spec.num_envs)
        self.num_envs = n
        self.slots = [int(e) for e in self.rng.choice(n, size=min(count, n), replace=False)]
        self.poses: list[Any] = []  # per step: [K, B, 7]
        self.steps: list[int] = []
        self.iteration = 0
        self._send_shapes(bytes(spec.robot_drawing_rrd))
        view.robots = len(self.slots)
        view.send_blueprint()

    def _send_shapes(self, rrd: bytes) -> None:
        import tempfile

        from rerun.experimental import RrdReader, send_chunks

        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "robot.rrd"
            path.write_bytes(rrd)
            chunks = [c for c in RrdReader(path).stream() if c.entity_path.startswith("/robot/")]
            for k in range(len(self.slots)):
                send_chunks(
                    [c.with_entity_path(f"/{ENVS}/{k}{c.entity_path}") for c in chunks],
                    recording=self.view.rec,
                )

    def envs_for(self, iteration: int) -> list[int]:
        """The envs to ask poses of in the rollout of ``iteration`` (none between draws)."""
        return list(self.slots) if iteration % self.every == 0 else []

    def add(self, iteration: int, step: int, poses: Any, dones: Any) -> None:
        """One step's poses (f32 [K, B, 7], or None) and dones (bool [N]); re-choose ended envs."""
        self.iteration = iteration
        if poses is not None and len(poses) == len(self.slots):
            self.poses.append(self.np.array(poses, dtype=self.np.float32))
            self.steps.append(step)
        for k, env in enumerate(self.slots):
            if bool(dones[env]):
                free = sorted(set(range(self.num_envs)) - set(self.slots))
                if free:
                    self.slots[k] = int(self.rng.choice(free))
                    self.view.event(
                        iteration, f"env slot {k}: env {env} ended, now env {self.slots[k]}"
                    )

    def flush(self) -> None:
        """Send the buffered steps (one batch per body)."""
        if not self.poses:
            return
        rr, np = self.view.rr, self.np
        poses = np.stack(self.poses)  # [T, K, B, 7]
        t = len(self.steps)
        indexes = [
            rr.TimeColumn(STEP_TIMELINE, sequence=self.steps),
            rr.TimeColumn(TIMELINE, sequence=[self.view.offset + self.iteration] * t),
        ]
        for k in range(poses.shape[1]):
            for b, body in enumerate(self.bodies):
                self.view.rec.send_columns(
                    f"{ENVS}/{k}/robot/{body}",
                    indexes=indexes,
                    columns=rr.Transform3D.columns(
                        translation=poses[:, k, b, :3], quaternion=poses[:, k, b, 3:]
                    ),
                )
        self.poses.clear()
        self.steps.clear()


def robot_drawer(view: LiveView, spec: Any, seed: int) -> RobotDrawer | None:
    """The drawer of ``view.target``'s envs, or None (none asked, or a server too old to draw)."""
    if view.target.envs <= 0:
        return None
    if not spec.body_names or not spec.robot_drawing_rrd:
        print(
            "warning: the server sends no robot drawing: the live view shows curves only",
            file=sys.stderr,
        )
        return None
    return RobotDrawer(view, spec, view.target.envs, view.target.every, seed)


class TensorBoardLog:
    """The run's scalars as TensorBoard events in ``log_dir`` (the CSV's names, step = iteration).

    Args:
        log_dir: The run's folder (``events.out.tfevents.*`` go beside ``progress.csv``).
    """

    def __init__(self, log_dir: Path) -> None:
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:
            raise ViewError("--tensorboard needs tensorboard: pip install tensorboard") from None
        self.writer = SummaryWriter(str(log_dir))

    def log(self, scalars: Mapping[str, float]) -> None:
        """One iteration's scalars."""
        step = int(scalars["iteration"])
        for name, value in scalars.items():
            self.writer.add_scalar(name, value, step)
        self.writer.flush()

    def close(self) -> None:
        """Flush and close the event file."""
        self.writer.close()
