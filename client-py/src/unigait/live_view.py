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

import math
import shutil
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
#: Where ``--view serve`` listens by default: loopback, the server's ``record --serve`` port.
DEFAULT_SERVE = "127.0.0.1:9876"
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
    """

    kind: ViewKind
    where: str


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
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()


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


#: Panels of the first tabs: (tab, panel title, scalar names or prefixes ending in ``/``).
PANELS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("progress", "mean episode reward", ("mean_episode_reward",)),
    ("progress", "mean reward per step", ("mean_step_reward",)),
    ("progress", "mean episode length (steps)", ("mean_episode_length",)),
    ("progress", "terrain level (mean, per type, per mode)", ("terrain_level", "terrain_level/")),
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
    return any(name.startswith(k) if k.endswith("/") else name == k for k in keys)


def blueprint(names: Sequence[str], reward_terms: Sequence[str], robots: int = 0) -> Any:
    """The view's layout: a tab per theme, each a grid of a few time series panels.

    Args:
        names: The scalar names the run logs.
        reward_terms: The session's reward terms (``episode_reward/<term>``), split by mode.
        robots: Envs the view draws (a 3D tab when non-zero).
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
    evals = [n for n in names if n.startswith("eval/")]
    for scenario in sorted({n.split("/")[1] for n in evals if n.count("/") >= 2}):
        panel("evaluation", scenario, [n for n in evals if n.startswith(f"eval/{scenario}/")])
    panel("evaluation", "milestone criteria met", [n for n in evals if n.count("/") == 1])
    for name in names:  # every other scalar, one panel each
        if name not in placed and name not in ("iteration",):
            panel("more", name, [name])
    views: list[Any] = []
    if robots:
        views.append(rrb.Spatial3DView(name="robots", origin="/world"))
    views += [rrb.Grid(*panels, name=tab) for tab, panels in tabs.items()]
    views.append(rrb.TextLogView(name="events", origin=f"/{EVENTS}"))
    return rrb.Blueprint(
        rrb.Tabs(*views),
        rrb.TimePanel(timeline=TIMELINE),
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
        #: Added to the runner's iteration on the timeline (a recipe's later stages).
        self.offset = 0
        self.url = ""
        self._server: _ServeProcess | None = None
        self.rec: rr.RecordingStream = rr.RecordingStream(
            "unigait", recording_id=recording_id(run_dir)
        )
        if target.kind == "save":
            path = Path(target.where)
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
            rec.send_blueprint(blueprint(self.names, self.reward_terms), make_active=True)
        rec.set_time(TIMELINE, sequence=self.offset + int(scalars["iteration"]))
        for name, value in scalars.items():
            rec.log(curve(name), rr.Scalars(float(value) if math.isfinite(value) else math.nan))

    def close(self) -> None:
        """Flush; stop serving (a served view ends with the run)."""
        self.rec.flush()
        self.rec.disconnect()
        if self._server is not None:
            self._server.close()


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
