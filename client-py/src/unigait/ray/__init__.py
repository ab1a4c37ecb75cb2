"""Simulation servers as Ray actors across a cluster, and the learner over them.

Install with the ``ray`` extra (``pip install "./client-py[ray]"``). The module places and
restarts servers and hands their addresses to the ordinary client; it knows nothing of the
protocol:

* :class:`ServerPool`: N ``unigait-server`` processes as actors with K CPUs each, spread over
  nodes by a placement group, health-checked, restarted when they die, shut down with the pool
  (how the binary reaches the nodes: see :mod:`unigait.ray.pool`);
* :class:`ServerCredentials`: TLS certificate, key and bearer token of the servers (paths on
  every node, or shipped in the actors' arguments: see :mod:`unigait.ray.credentials`), and the
  CA and token of the learner's connections and health checks;
* :func:`train_on_ray` (``python -m unigait train --ray [ADDRESS] --servers N
  --cpus-per-server K``): PPO over a pool; a lost server's shard moves to the restarted actor,
  its cut episodes count as truncated, and ``server_restarts`` is logged.

Example:
    >>> import ray  # doctest: +SKIP
    >>> from unigait.client import SessionConfig
    >>> from unigait.ray import ServerPool
    >>> ray.init()  # doctest: +SKIP
    >>> with ServerPool(2, cpus_per_server=1) as pool:  # doctest: +SKIP
    ...     with pool.open_session(SessionConfig(num_envs=64)) as session:
    ...         result = session.step(actions)  # f32 [64, 12] in, 32 envs per server
"""

from __future__ import annotations

from typing import Any

from unigait.ray.credentials import ServerCredentials
from unigait.ray.health import check_health, probe_health, wait_healthy
from unigait.ray.pool import PoolConfigError, ServerPlacement, ServerPool, ship_binary_env
from unigait.ray.server_actor import ServerActor

__all__ = [
    "PoolConfigError",
    "ResilientRunner",
    "ServerActor",
    "ServerCredentials",
    "ServerPlacement",
    "ServerPool",
    "check_health",
    "probe_health",
    "ship_binary_env",
    "train_on_ray",
    "train_with_pool",
    "wait_healthy",
]

_TRAINING = ("ResilientRunner", "train_on_ray", "train_with_pool")


def __getattr__(name: str) -> Any:
    # The learner needs torch; the actors' workers import this package without it.
    if name in _TRAINING:
        from unigait.ray import train

        return getattr(train, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
