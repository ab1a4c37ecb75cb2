"""The learner on Ray: PPO over a :class:`ServerPool`, carrying on when a server is lost.

The learner runs in the Ray driver (one process: rollouts, PPO and estimator updates); the
simulation runs in the pool's server actors. Python API::

    from unigait.config import load_config
    from unigait.ray import train_on_ray

    train_on_ray(load_config(None, ["env.num_envs=4096"]), address="auto", num_servers=8,
                 cpus_per_server=4)

    # servers on the nodes' IPs, TLS + token (files mounted on every node; the learner's CA)
    train_on_ray(cfg, address="auto", num_servers=8, cpus_per_server=4, host=None,
                 credentials=ServerCredentials(cert_file="/etc/unigait/tls/tls.crt",
                                               key_file="/etc/unigait/tls/tls.key",
                                               token_file="/etc/unigait/token/token",
                                               token=token, ca=ca_pem))
"""

from __future__ import annotations

import json
import logging
import sys
import tempfile
from pathlib import Path
from typing import Any

from unigait.config import TrainConfig, session_config
from unigait.ray.credentials import ServerCredentials
from unigait.ray.pool import PoolConfigError, ServerPool, ship_binary_env
from unigait.runners import OnPolicyRunner, train

# session_config stays importable from here: the Ray tests build their sessions with it.
__all__ = ["ResilientRunner", "session_config", "train_on_ray", "train_with_pool"]

log = logging.getLogger(__name__)


class ResilientRunner(OnPolicyRunner):
    """:class:`OnPolicyRunner` that also logs ``server_restarts``.

    ``server_restarts`` is the number of shard sessions recreated since the start because their
    server was lost (cumulative; a column of ``progress.csv``).
    """

    def rollout(self) -> dict[str, float]:
        """See :meth:`OnPolicyRunner.rollout`; adds ``server_restarts``."""
        out = super().rollout()
        out["server_restarts"] = float(getattr(self.env.session, "server_restarts", 0))
        return out


def train_with_pool(
    pool: ServerPool,
    cfg: TrainConfig,
    *,
    resume: str | Path | None = None,
    init_from: str | Path | None = None,
    stage: str | None = None,
) -> list[dict[str, float]]:
    """:func:`unigait.runners.train` over a started pool.

    Args:
        pool: Started servers; the batch is sharded over them, lost ones are replaced.
        cfg: The training config (``env.servers`` is ignored).
        resume: A checkpoint to continue from.
        init_from: A checkpoint whose networks (only) start the run (staged training).
        stage: The command line of this run, kept in its checkpoints (model cards show it).

    Returns:
        The logged scalars of each iteration.
    """
    where = (
        f"{pool.num_servers} Ray server actor(s) ({pool.cpus_per_server} CPU each: "
        f"{', '.join(pool.addresses)})"
    )
    return train(
        cfg,
        pool.open_session,
        resume=resume,
        init_from=init_from,
        stage=stage,
        runner_class=ResilientRunner,
        servers=where,
    )


def train_on_ray(
    cfg: TrainConfig,
    *,
    address: str | None = None,
    num_servers: int = 1,
    cpus_per_server: int = 1,
    resume: str | Path | None = None,
    init_from: str | Path | None = None,
    stage: str | None = None,
    ship_binary: str | Path | None = None,
    pool_options: dict[str, Any] | None = None,
    credentials: ServerCredentials | None = None,
    host: str | None = "127.0.0.1",
) -> list[dict[str, float]]:
    """Start a server pool on a Ray cluster, train over it, shut it down.

    Args:
        cfg: The training config; ``env.server_bin``, if set, is the binary's path on the nodes.
        address: Ray address (``"auto"``, ``"HOST:6379"``); None or "": ``ray.init()``'s own
            choice (``$RAY_ADDRESS``, the latest local cluster, else a new local instance). An
            already connected driver is used as it is.
        num_servers: Server actors (shards).
        cpus_per_server: CPUs (and server threads) per actor.
        resume: A checkpoint to continue from.
        init_from: A checkpoint whose networks (only) start the run.
        stage: The command line of this run, kept in its checkpoints.
        ship_binary: Upload this local server binary to the nodes with the job (see
            :func:`unigait.ray.pool.ship_binary_env`); needs this call to connect to Ray.
        pool_options: More :class:`ServerPool` arguments (``extra_args``, ``strategy``, ...).
        credentials: TLS and token of the servers and the learner (see
            :class:`~unigait.ray.credentials.ServerCredentials`).
        host: Address the servers bind (None: each node's IP, which needs ``credentials``).

    Returns:
        The logged scalars of each iteration.
    """
    import ray

    if cfg.env.servers:
        raise PoolConfigError(
            "train_on_ray starts its own servers: leave env.servers (--server) empty"
        )
    if not logging.getLogger().handlers:  # show lost servers and restarts
        logging.basicConfig(stream=sys.stderr, format="%(name)s: %(message)s")
    connected_here = not ray.is_initialized()
    options = dict(pool_options or {})
    options.setdefault("credentials", credentials)
    options.setdefault("host", host)
    ServerPool(num_servers, cpus_per_server, **options)  # check the arguments before Ray starts
    if cfg.env.server_bin:
        options.setdefault("binary", cfg.env.server_bin)
    with tempfile.TemporaryDirectory(prefix="unigait-ship-") as staging:
        runtime_env = None
        if ship_binary is not None:
            if not connected_here:
                raise PoolConfigError("ship_binary: the job's runtime env is set when Ray connects")
            runtime_env, options["binary"] = ship_binary_env(ship_binary, staging)
        if connected_here:
            ray.init(address=address or None, runtime_env=runtime_env)
    try:
        with ServerPool(num_servers, cpus_per_server, **options) as pool:
            security = "plaintext"
            if pool.credentials is not None:
                security = "TLS" if pool.credentials.tls else "plaintext"
                security += " + token" if pool.credentials.server_token else ""
            for m in pool.members:
                print(
                    f"server {m.index}: {m.address} on node {m.node_ip} ({m.node_id[:12]}), "
                    f"{security}"
                )
            history = train_with_pool(pool, cfg, resume=resume, init_from=init_from, stage=stage)
            restarts = sum(pool.restarts)
            if restarts:
                print(f"servers restarted during the run: {json.dumps(pool.restarts)}")
            return history
    finally:
        if connected_here:
            ray.shutdown()
