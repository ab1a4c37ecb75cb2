"""One env batch split across several servers, stepped concurrently."""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Protocol

import numpy as np

from unigait.client.closing import ClosesOnExit
from unigait.client.session import Client, Session
from unigait.client.spec import Spec
from unigait.client.types import SessionConfig, StepResult


class SessionLike(Protocol):
    """What the vector envs need from a session (a :class:`Session` or :class:`ShardedSession`)."""

    spec: Spec
    initial: StepResult

    def step(self, actions: np.ndarray, *, reward_terms: bool = False) -> StepResult:
        """One batched step; ``actions`` f32 [N, 12]."""
        ...

    def reset(self, mask: np.ndarray | None = None) -> StepResult:
        """Reset all envs or those selected by ``mask`` (bool [N])."""
        ...

    def close(self) -> None:
        """Free the session."""
        ...


def split_envs(num_envs: int, num_shards: int) -> list[int]:
    """Env counts per shard, as even as possible, larger shards first.

    Example:
        >>> split_envs(10, 3)
        [4, 3, 3]
    """
    if num_shards < 1 or num_envs < num_shards:
        raise ValueError(f"cannot split {num_envs} envs over {num_shards} servers")
    base, extra = divmod(num_envs, num_shards)
    return [base + (1 if i < extra else 0) for i in range(num_shards)]


class ShardedSession(ClosesOnExit):
    """A session per server, presented as one batch in env order.

    Shard ``i`` holds envs ``offsets[i] .. offsets[i] + counts[i]`` and is seeded with
    ``config.seed + i``. Steps and resets go to every shard at once (one thread per shard; gRPC
    waits release the GIL) and the results are concatenated.

    Args:
        clients: One connection per server.
        config: The config of the whole batch (``num_envs`` is the total).
        owns_clients: Close the clients with the session.
    """

    def __init__(
        self, clients: Sequence[Client], config: SessionConfig, *, owns_clients: bool = False
    ) -> None:
        self.counts = split_envs(config.num_envs, len(clients))
        self.offsets = [int(o) for o in np.cumsum([0, *self.counts[:-1]])]
        self._clients = list(clients)
        self._owns_clients = owns_clients
        self._pool = ThreadPoolExecutor(max_workers=len(clients), thread_name_prefix="unigait")
        configs = [
            SessionConfig(**{**config.__dict__, "num_envs": n, "seed": config.seed + i})
            for i, n in enumerate(self.counts)
        ]
        futures = [
            self._pool.submit(c.create_session, cfg)
            for c, cfg in zip(clients, configs, strict=True)
        ]
        self.sessions: list[Session] = []
        errors = []
        for f in futures:
            try:
                self.sessions.append(f.result())
            except Exception as err:  # close what was opened, then re-raise the first error
                errors.append(err)
        if errors:
            self.close()
            raise errors[0]
        self.spec = self.sessions[0].spec.with_num_envs(config.num_envs)
        self.initial = StepResult.concat([s.initial for s in self.sessions], self.offsets)

    @property
    def num_envs(self) -> int:
        """N, over all shards."""
        return self.spec.num_envs

    def _rows(self, array: np.ndarray, i: int) -> np.ndarray:
        return array[self.offsets[i] : self.offsets[i] + self.counts[i]]

    def step(self, actions: np.ndarray, *, reward_terms: bool = False) -> StepResult:
        """One step of every shard (see :meth:`Session.step`); ``actions`` f32 [N, 12]."""
        actions = np.asarray(actions)
        futures = [
            self._pool.submit(s.step, self._rows(actions, i), reward_terms=reward_terms)
            for i, s in enumerate(self.sessions)
        ]
        return StepResult.concat([f.result() for f in futures], self.offsets)

    def reset(self, mask: np.ndarray | None = None) -> StepResult:
        """Reset all envs or those selected by ``mask`` (bool [N]) on every shard."""
        futures = [
            self._pool.submit(s.reset, None if mask is None else self._rows(np.asarray(mask), i))
            for i, s in enumerate(self.sessions)
        ]
        return StepResult.concat([f.result() for f in futures], self.offsets)

    def close(self) -> None:
        """Close every shard's session (and the clients when owned)."""
        for s in self.sessions:
            s.close()
        self.sessions = []
        self._pool.shutdown(wait=False)
        if self._owns_clients:
            for c in self._clients:
                c.close()


def open_session(
    addresses: str | Sequence[str], config: SessionConfig, *, connect_timeout_s: float = 10.0
) -> Session | ShardedSession:
    """Connect and create a session; several addresses shard the batch across servers.

    Args:
        addresses: One ``host:port`` or several (also accepted: a comma-separated string).
        config: Session config; ``num_envs`` is the total over all servers.
        connect_timeout_s: Wait this long for each server.

    Returns:
        A :class:`Session` for one server, a :class:`ShardedSession` for several. Closing it
        closes the connections too.
    """
    if isinstance(addresses, str):
        addresses = [a.strip() for a in addresses.split(",") if a.strip()]
    if not addresses:
        raise ValueError("no server address given")
    clients = [Client(a, connect_timeout_s=connect_timeout_s) for a in addresses]
    if len(clients) == 1:
        try:
            session = clients[0].create_session(config)
        except Exception:
            clients[0].close()
            raise
        session._owns_client = True
        return session
    return ShardedSession(clients, config, owns_clients=True)
