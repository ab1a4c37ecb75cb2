"""A pool of ``unigait-server`` processes as Ray actors, spread over the cluster's nodes.

The pool reserves one placement-group bundle of ``cpus_per_server`` CPUs per server (strategy
``SPREAD``: one per node while nodes last), starts a :class:`ServerActor` in each bundle (server
``--threads`` = the bundle's CPUs), waits until every server answers the gRPC health check from
the learner's side, and hands out their addresses. The pool only places and restarts servers;
the learner talks to them with the ordinary client (:func:`unigait.client.open_session`), and
:meth:`ServerPool.replacement` is the ``reconnect`` hook that lets a sharded session move a
lost shard to the restarted actor.

How the server binary reaches the nodes:

* **Default: found on the node** (``binary=None``): ``$UNIGAIT_SERVER_BIN`` on the node, else the
  repository build of an editable install, else ``unigait-server`` on the node's ``PATH`` (where
  the images of ``deploy/`` put it). The binary is native code for the node's CPU and C library,
  so it belongs in the node's image, built once with the same toolchain, versioned with the
  image, and not uploaded again by every job.
* **An explicit path** (``binary="/opt/unigait/bin/unigait-server"``): the same path on every
  node (a shared volume, a different install prefix).
* **Shipped with the job** (:func:`ship_binary_env`): the driver's binary travels in the job's
  Ray ``runtime_env`` ``working_dir`` (``ray.init(runtime_env=...)``; Ray 2.60 takes local
  directories only at the job level, and keeps the executable bit) and the actors run
  ``./unigait-server`` from there. For clusters of identical machines whose image lacks the
  binary; it costs an upload per job (about 40 MB stripped, 360 MB with the release profile's
  line tables; Ray caps a package at 512 MiB) and fails on nodes of another platform. A
  per-actor ``runtime_env`` (``ServerPool(runtime_env=...)``) may name a remote package instead
  (``{"working_dir": "s3://.../unigait-server.zip"}`` with ``binary="./unigait-server"``).

Networking and credentials: the servers bind loopback by default, which serves a learner on the
same machine (a one-node cluster, the tests' two-node local cluster). Beyond it (``host=None``:
each node's IP) the server requires TLS and a bearer token, so the pool refuses to start such
servers without ``credentials`` (:class:`~unigait.ray.credentials.ServerCredentials`: the
certificate, key and token as paths on every node, e.g. mounted Kubernetes secrets, or shipped
in the call that starts each server, never in the actors' creation arguments; see
:mod:`unigait.ray.credentials` for the choice) and passes
``--allow-remote``. The same credentials give the learner's sessions the CA and the token, and
the health checks the CA. After the servers come up the pool makes one authenticated call to
each, so a wrong or missing token fails the start at once with the server's answer.

Restarts: each actor has ``max_restarts`` (default: unlimited). When its server dies the actor
ends itself, Ray starts it again in the same bundle (or, if the node is gone, wherever the
placement group's bundle is rescheduled), and :meth:`ServerPool.replacement` starts a new server
in the new actor (on a new port, with the credentials again).
Shutdown (:meth:`ServerPool.close`, also on leaving ``with``) stops every server, kills the
actors without restart and removes the placement group; a server whose actor dies any other way
is killed by the kernel (see :mod:`unigait.ray.server_actor`).
"""

from __future__ import annotations

import logging
import shutil
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import ray
from ray.util.placement_group import PlacementGroup, placement_group, remove_placement_group
from ray.util.scheduling_strategies import PlacementGroupSchedulingStrategy

from unigait.client.closing import ClosesOnExit
from unigait.client.connection import parse_address
from unigait.client.errors import UnigaitError
from unigait.client.session import Client
from unigait.client.sharded import ShardedSession, open_session
from unigait.client.types import SessionConfig
from unigait.ray.credentials import ServerCredentials
from unigait.ray.health import check_health, wait_healthy
from unigait.ray.server_actor import ServerActor

log = logging.getLogger(__name__)

#: Name the shipped binary gets inside the job's ``working_dir``.
SHIPPED_NAME = "unigait-server"


def ship_binary_env(binary: str | Path, directory: str | Path) -> tuple[dict[str, Any], str]:
    """A job-level runtime env that carries the server binary to every node.

    Args:
        binary: The local binary.
        directory: An empty directory to stage it in (keep it until ``ray.init`` returned).

    Returns:
        ``(runtime_env, binary_on_nodes)``: pass the first to ``ray.init(runtime_env=...)`` and
        the second as the pool's ``binary`` (relative to the actors' working directory).
    """
    source = Path(binary).resolve()
    if not source.is_file():
        raise FileNotFoundError(f"no server binary to ship at {source}")
    shutil.copy2(source, Path(directory) / SHIPPED_NAME)
    return {"working_dir": str(directory)}, f"./{SHIPPED_NAME}"


class PoolConfigError(ValueError):
    """A pool or a Ray training run asked for what cannot work, refused before anything starts."""


@dataclass(frozen=True)
class ServerPlacement:
    """Where one pool member's server runs.

    Attributes:
        index: Position in the pool (= the shard it serves).
        address: ``host:port`` of the server.
        pid: Server process id (on its node).
        node_id: Ray node id.
        node_ip: The node's IP address.
    """

    index: int
    address: str
    pid: int
    node_id: str
    node_ip: str

    @classmethod
    def from_info(cls, index: int, info: dict[str, Any]) -> ServerPlacement:
        """Build from :meth:`ServerActor.info`."""
        return cls(index, info["address"], int(info["pid"]), info["node_id"], info["node_ip"])


class ServerPool(ClosesOnExit):
    """N ``unigait-server`` processes as Ray actors with K CPUs each, spread over nodes.

    Needs a connected Ray driver (``ray.init(...)`` before :meth:`start`).

    Args:
        num_servers: N servers (= shards of the learner's batch).
        cpus_per_server: K CPUs per server: the bundle size and the server's ``--threads``.
        binary: Server binary on the nodes (see the module docstring); None: found there.
        host: Address the servers bind (loopback by default; None: the node's IP, which needs
            ``credentials`` with TLS and a token).
        extra_args: More ``serve`` flags (``--max-envs``, ...).
        strategy: Placement strategy (``"SPREAD"``; ``"STRICT_SPREAD"`` insists on distinct
            nodes, ``"PACK"`` fills nodes first).
        max_restarts: Restarts of each actor (-1: unlimited).
        startup_timeout_s: Wait this long for the placement group and the first servers.
        restart_timeout_s: Wait this long for a lost server's replacement.
        hung_timeout_s: A server that runs but fails the health check this long (while its
            shard waits for a replacement) has its actor restarted.
        echo_output: Copy the servers' output into Ray's worker logs.
        runtime_env: Ray runtime env of the actors (remote URIs only: local directories go to
            ``ray.init``, see :func:`ship_binary_env`).
        credentials: TLS and token of the servers and of the learner's connections (None:
            plaintext, no token: loopback only).

    Raises:
        PoolConfigError: Servers beyond loopback without TLS and a token (the server refuses
            them), or no server or CPU at all.

    Attributes:
        members: Where each server runs (updated after restarts).
        restarts: Restarts seen per server (a new server process behind the same actor).
        pids_seen: Every server process id the pool has seen, for leak checks.
        pool_id: Random id in every server's environment (``$UNIGAIT_RAY_POOL``).
    """

    def __init__(
        self,
        num_servers: int,
        cpus_per_server: int = 1,
        *,
        binary: str | None = None,
        host: str | None = "127.0.0.1",
        extra_args: Sequence[str] = (),
        strategy: str = "SPREAD",
        max_restarts: int = -1,
        startup_timeout_s: float = 120.0,
        restart_timeout_s: float = 300.0,
        hung_timeout_s: float = 30.0,
        echo_output: bool = False,
        runtime_env: dict[str, Any] | None = None,
        credentials: ServerCredentials | None = None,
    ) -> None:
        if num_servers < 1 or cpus_per_server < 1:
            raise PoolConfigError("a pool needs at least one server with at least one CPU")
        beyond_loopback = host is None or not parse_address(f"[{host}]:0").is_loopback
        if beyond_loopback and not (
            credentials is not None and credentials.tls and credentials.server_token
        ):
            raise PoolConfigError(
                f"servers bound to {host or 'the nodes IPs'} are reachable beyond loopback, where "
                "unigait-server requires TLS and a bearer token: pass credentials="
                "ServerCredentials(cert_file=..., key_file=..., token=...) (CLI: "
                "--server-tls-cert, --server-tls-key and --token-file or $UNIGAIT_TOKEN)"
            )
        self.credentials = credentials
        self.pool_id = uuid.uuid4().hex
        self.num_servers = num_servers
        self.cpus_per_server = cpus_per_server
        self.members: list[ServerPlacement] = []
        self.restarts = [0] * num_servers
        self.pids_seen: set[int] = set()
        self._binary = binary
        self._host = host
        self._extra_args = list(extra_args)
        self._strategy = strategy
        self._max_restarts = max_restarts
        self._startup_timeout_s = startup_timeout_s
        self._restart_timeout_s = restart_timeout_s
        self._hung_timeout_s = hung_timeout_s
        self._echo = echo_output
        self._runtime_env = dict(runtime_env or {})
        self._pg: PlacementGroup | None = None
        self._actors: list[Any] = []

    @property
    def addresses(self) -> list[str]:
        """``host:port`` of each server, in pool order."""
        return [m.address for m in self.members]

    def _actor_options(self, index: int) -> dict[str, Any]:
        assert self._pg is not None
        options: dict[str, Any] = {
            "num_cpus": self.cpus_per_server,
            "max_restarts": self._max_restarts,
            "max_task_retries": -1,  # calls wait for a restarting actor
            "scheduling_strategy": PlacementGroupSchedulingStrategy(
                self._pg, placement_group_bundle_index=index
            ),
        }
        if self._runtime_env:
            options["runtime_env"] = self._runtime_env
        return options

    def start(self) -> list[str]:
        """Reserve the bundles, start the servers, wait until each is healthy.

        Returns:
            The servers' addresses.

        Raises:
            TimeoutError: The cluster cannot hold the bundles, or a server did not come up.
            ray.exceptions.RayActorError: A server failed to start (the cause is attached).
        """
        if not ray.is_initialized():
            raise RuntimeError("connect to Ray first: ray.init(address)")
        try:
            bundles = [{"CPU": float(self.cpus_per_server)} for _ in range(self.num_servers)]
            self._pg = placement_group(bundles, strategy=self._strategy)
            ready, _ = ray.wait([self._pg.ready()], timeout=self._startup_timeout_s)
            if not ready:
                raise TimeoutError(
                    f"Ray could not reserve {self.num_servers} x {bundles[0]} ({self._strategy}) "
                    f"within {self._startup_timeout_s} s; the cluster has "
                    f"{ray.cluster_resources()}"
                )
            remote = ray.remote(ServerActor)
            self._actors = [
                remote.options(**self._actor_options(i)).remote(
                    self._binary,
                    self.cpus_per_server,
                    self._host,
                    self._extra_args,
                    self._startup_timeout_s,
                    self._echo,
                    self.pool_id,
                )
                for i in range(self.num_servers)
            ]
            # The credentials go in a call, not in the creation arguments that Ray keeps.
            infos = ray.get(
                [a.start.remote(self.credentials) for a in self._actors],
                timeout=2 * self._startup_timeout_s,
            )
            self.members = [ServerPlacement.from_info(i, info) for i, info in enumerate(infos)]
            for m in self.members:
                self.pids_seen.add(m.pid)
                wait_healthy(m.address, self._startup_timeout_s, **self._health_options())
                self._check_access(m)
                log.info(
                    "server %d: %s (pid %d) on node %s (%s), %d CPU(s)",
                    m.index,
                    m.address,
                    m.pid,
                    m.node_id[:12],
                    m.node_ip,
                    self.cpus_per_server,
                )
        except BaseException:
            self.close()
            raise
        return self.addresses

    def _health_options(self) -> dict[str, Any]:
        return dict(self.credentials.health_options()) if self.credentials else {}

    def connection_options(self) -> dict[str, Any]:
        """The learner's :class:`~unigait.client.Client` keyword arguments (CA, token)."""
        return dict(self.credentials.connection_options()) if self.credentials else {}

    def _check_access(self, member: ServerPlacement, timeout_s: float = 10.0) -> None:
        """One authenticated call, so that a wrong or missing token fails here, not mid-run.

        Raises:
            PermissionError: The server refused the learner (UNAUTHENTICATED), with its words.
        """
        try:
            with Client(
                member.address, connect_timeout_s=timeout_s, **self.connection_options()
            ) as client:
                client.server_info()
        except UnigaitError as err:
            if err.code_name != "UNAUTHENTICATED":
                raise
            given = "a token" if self.connection_options().get("token") else "no token"
            raise PermissionError(
                f"server {member.index} ({member.address}) refused the learner, which sent "
                f"{given}: {err.details} (the learner's token must be the servers' token: "
                "--token-file / $UNIGAIT_TOKEN, ServerCredentials.token)"
            ) from err

    def info(self, index: int, timeout_s: float | None = None) -> dict[str, Any]:
        """:meth:`ServerActor.info` of server ``index`` (waits for a restarting actor)."""
        return ray.get(self._actors[index].info.remote(), timeout=timeout_s)

    def replacement(self, index: int, lost_address: str) -> str:
        """The address where server ``index`` serves again after ``lost_address`` was lost.

        This is the ``reconnect`` hook of :class:`ShardedSession`: it waits (up to
        ``restart_timeout_s``) until the actor runs a live server that answers the health check
        from here. The server may be the same one (a session lost for another reason) or the
        one a restarted actor started; a new server process counts as a restart. A server that
        runs but does not answer for ``hung_timeout_s`` has its actor killed and restarted.

        Raises:
            TimeoutError: No healthy server within ``restart_timeout_s``.
            ray.exceptions.ActorDiedError: The actor is gone for good (restarts used up).
        """
        deadline = time.monotonic() + self._restart_timeout_s
        silent_since: float | None = None
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(
                    f"server {index} ({lost_address}) not back within {self._restart_timeout_s} s"
                )
            try:
                info = self.info(index, timeout_s=remaining)
            except ray.exceptions.GetTimeoutError:
                continue
            except ray.exceptions.ActorUnavailableError:  # restarting; try again shortly
                time.sleep(0.2)
                continue
            if not info["address"]:  # a restarted actor: start its server
                try:
                    info = ray.get(
                        self._actors[index].start.remote(self.credentials), timeout=remaining
                    )
                except (ray.exceptions.GetTimeoutError, ray.exceptions.ActorUnavailableError):
                    continue
            healthy = info["alive"] and check_health(
                info["address"], timeout_s=min(2.0, remaining), **self._health_options()
            )
            if healthy:
                break
            if info["alive"]:  # running but not answering: hung, or its node is cut off
                silent_since = silent_since or time.monotonic()
                if time.monotonic() - silent_since > self._hung_timeout_s:
                    log.warning(
                        "server %d (%s) is running but has not answered the health check for "
                        "%.0f s; restarting its actor",
                        index,
                        info["address"],
                        self._hung_timeout_s,
                    )
                    ray.kill(self._actors[index], no_restart=False)
                    silent_since = None
            time.sleep(0.2)
        member = ServerPlacement.from_info(index, info)
        if member.pid != self.members[index].pid:
            self.restarts[index] += 1
            self.pids_seen.add(member.pid)
            log.warning(
                "server %d restarted: %s (pid %d) on node %s replaces %s (restart %d)",
                index,
                member.address,
                member.pid,
                member.node_id[:12],
                lost_address,
                self.restarts[index],
            )
        self.members[index] = member
        return member.address

    def open_session(
        self,
        config: SessionConfig,
        *,
        step_timeout_s: float | None = 120.0,
        connect_timeout_s: float = 10.0,
    ) -> ShardedSession:
        """A session sharded over the pool that survives lost servers.

        Args:
            config: The whole batch's config (``num_envs`` over all servers).
            step_timeout_s: A server silent this long in a step counts as lost (a node that
                vanished without closing its connections).
            connect_timeout_s: Wait this long for each server's channel.
        """
        session = open_session(
            self.addresses,
            config,
            connect_timeout_s=connect_timeout_s,
            reconnect=self.replacement,
            step_timeout_s=step_timeout_s,
            **self.connection_options(),
        )
        assert isinstance(session, ShardedSession)
        return session

    def close(self, timeout_s: float = 15.0) -> None:
        """Stop every server, kill the actors (no restart), remove the placement group."""
        actors, self._actors = self._actors, []
        if actors:
            stops = [a.stop.remote() for a in actors]
            ray.wait(stops, num_returns=len(stops), timeout=timeout_s)
            for a in actors:
                ray.kill(a, no_restart=True)
        if self._pg is not None:
            remove_placement_group(self._pg)
            self._pg = None

    def __enter__(self) -> ServerPool:
        if not self._actors:
            self.start()
        return self
