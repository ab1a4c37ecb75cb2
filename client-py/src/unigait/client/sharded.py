"""One env batch split across several servers, stepped concurrently, surviving lost servers."""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeoutError
from typing import Protocol

import grpc
import numpy as np

from unigait.client.closing import ClosesOnExit
from unigait.client.errors import ProtocolError, UnigaitError
from unigait.client.session import Client, Session
from unigait.client.spec import Spec
from unigait.client.types import SessionConfig, StepResult

log = logging.getLogger(__name__)

#: ``reconnect(shard, lost_address) -> address``: where shard ``shard`` continues once the
#: server at ``lost_address`` is gone (blocks until that server answers; raises to give up).
Reconnect = Callable[[int, str], str]

#: Status codes meaning "the server, or its session, is gone" rather than "the request was wrong".
LOST_CODES = frozenset(
    {grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.CANCELLED, grpc.StatusCode.NOT_FOUND}
)


class SessionLike(Protocol):
    """What the vector envs need from a session (a :class:`Session` or :class:`ShardedSession`)."""

    spec: Spec
    initial: StepResult

    def step(
        self, actions: np.ndarray, *, reward_terms: bool = False, draw_envs: Sequence[int] = ()
    ) -> StepResult:
        """One batched step; ``actions`` f32 [N, 12]; ``draw_envs``: envs to return poses of."""
        ...

    def reset(self, mask: np.ndarray | None = None) -> StepResult:
        """Reset all envs or those selected by ``mask`` (bool [N])."""
        ...

    def close(self) -> None:
        """Free the session."""
        ...


class ShardLostError(RuntimeError):
    """A shard's server was lost and could not be replaced."""


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


def is_lost(err: BaseException) -> bool:
    """Whether ``err`` means the server (or its session) is gone, not a bad request."""
    if isinstance(err, UnigaitError):
        return err.code in LOST_CODES
    return isinstance(err, ProtocolError | FutureTimeoutError)


class ShardedSession(ClosesOnExit):
    """A session per server, presented as one batch in env order.

    Shard ``i`` holds envs ``offsets[i] .. offsets[i] + counts[i]`` and is seeded with
    ``config.seed + i``. Steps and resets go to every shard at once (one thread per shard; gRPC
    waits release the GIL) and the results are concatenated.

    With ``reconnect``, a lost server does not end the run. When a shard's call fails with a
    status of :data:`LOST_CODES`, a broken stream, or no reply within ``step_timeout_s``, the
    shard's session is dropped, ``reconnect`` names the server to continue on (the restarted
    one), a new session is created there (seed ``config.seed + i + generation * shards``) and
    the step returns for that shard: the new first observations, zero reward, and every env of
    the shard *truncated* (not terminated), with final rows = the last observation, labels and
    privileged values this session returned for those envs, so that the learner bootstraps the
    cut episodes from the critic. Each such event is logged (warning) and counted in
    :attr:`server_restarts`; the other shards' sessions are untouched.

    Args:
        clients: One connection per server.
        config: The config of the whole batch (``num_envs`` is the total).
        owns_clients: Close the clients with the session.
        reconnect: Where a lost shard continues (None: a lost server raises, as any error).
        step_timeout_s: With ``reconnect``, a shard silent this long counts as lost (None: wait).
        max_consecutive_losses: Give up (:class:`ShardLostError`) when a shard is lost this many
            times in a row without a successful call in between.
        connect_timeout_s: Wait this long for a replacement server's channel.

    Attributes:
        counts: Envs per shard.
        offsets: Index of each shard's first env.
        sessions: The current session of each shard.
        server_restarts: Sessions recreated after their server was lost.
    """

    def __init__(
        self,
        clients: Sequence[Client],
        config: SessionConfig,
        *,
        owns_clients: bool = False,
        reconnect: Reconnect | None = None,
        step_timeout_s: float | None = None,
        max_consecutive_losses: int = 3,
        connect_timeout_s: float = 10.0,
    ) -> None:
        self.counts = split_envs(config.num_envs, len(clients))
        self.offsets = [int(o) for o in np.cumsum([0, *self.counts[:-1]])]
        self.server_restarts = 0
        self._config = config
        self._clients = list(clients)
        self._owned = [owns_clients] * len(clients)
        self._reconnect = reconnect
        self._step_timeout_s = step_timeout_s if reconnect is not None else None
        self._max_losses = max_consecutive_losses
        self._connect_timeout_s = connect_timeout_s
        self._generation = [0] * len(clients)
        self._losses = [0] * len(clients)
        self._pool = ThreadPoolExecutor(max_workers=len(clients), thread_name_prefix="unigait")
        futures = [
            self._pool.submit(c.create_session, self._shard_config(i))
            for i, c in enumerate(clients)
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
        # obs, labels, privileged of every env as last returned: the final rows of cut episodes.
        self._last: tuple[np.ndarray, ...] = (
            self.initial.obs,
            self.initial.labels,
            self.initial.privileged,
        )
        self._episode_steps = np.zeros(config.num_envs, dtype=np.int64)

    @property
    def num_envs(self) -> int:
        """N, over all shards."""
        return self.spec.num_envs

    @property
    def addresses(self) -> list[str]:
        """The server of each shard (changes when a lost shard moves)."""
        return [c.address for c in self._clients]

    def _shard_config(self, i: int) -> SessionConfig:
        seed = self._config.seed + i + self._generation[i] * len(self._clients)
        # Each shard starts its own envs' levels; a shard that replaces a lost one starts afresh.
        levels, pairs = self._config.terrain_levels, self._config.terrain_mode_levels
        first, count = self.offsets[i], self.counts[i]
        fresh = self._generation[i] != 0
        levels = () if fresh or not levels else levels[first : first + count]
        pairs = () if fresh or not pairs else pairs[2 * first : 2 * (first + count)]
        return dataclasses.replace(
            self._config,
            num_envs=count,
            seed=seed,
            terrain_levels=levels,
            terrain_mode_levels=pairs,
        )

    def _rows(self, array: np.ndarray, i: int) -> np.ndarray:
        return array[self.offsets[i] : self.offsets[i] + self.counts[i]]

    def _gather(
        self, futures: list[Future[StepResult]], cut: bool, reward_terms: bool
    ) -> StepResult:
        """Wait for every shard, replacing lost ones (see the class docstring)."""
        return StepResult.concat(self._gather_parts(futures, cut, reward_terms), self.offsets)

    def _gather_parts(
        self, futures: list[Future[StepResult]], cut: bool, reward_terms: bool
    ) -> list[StepResult]:
        """Each shard's result, lost shards replaced (see the class docstring)."""
        parts: list[StepResult] = []
        for i, f in enumerate(futures):
            try:
                parts.append(f.result(timeout=self._step_timeout_s))
                self._losses[i] = 0
            except Exception as err:
                if self._reconnect is None or not is_lost(err):
                    raise
                if isinstance(err, FutureTimeoutError):
                    err = TimeoutError(f"no reply within {self._step_timeout_s} s")
                initial = self._replace(i, err)
                parts.append(self._cut(i, initial, reward_terms) if cut else initial)
        return parts

    def step(
        self, actions: np.ndarray, *, reward_terms: bool = False, draw_envs: Sequence[int] = ()
    ) -> StepResult:
        """One step of every shard (see :meth:`Session.step`); ``actions`` f32 [N, 12].

        ``draw_envs`` (indices over all shards) go to their shards; the poses come back in
        their order (none when a shard was lost in the step).
        """
        actions = np.asarray(actions)
        if any(not 0 <= g < self.num_envs for g in draw_envs):
            raise ValueError(f"draw_envs {list(draw_envs)}: each must be in 0..{self.num_envs - 1}")
        shard_of = [
            (int(np.searchsorted(self.offsets, g, side="right")) - 1, int(g)) for g in draw_envs
        ]
        local = [
            [g - self.offsets[i] for s, g in shard_of if s == i] for i in range(len(self.sessions))
        ]
        futures = [
            self._pool.submit(
                s.step, self._rows(actions, i), reward_terms=reward_terms, draw_envs=local[i]
            )
            for i, s in enumerate(self.sessions)
        ]
        parts = self._gather_parts(futures, True, reward_terms)
        result = StepResult.concat(parts, self.offsets)
        if draw_envs:
            result.body_poses = _poses_in_order(parts, local, [s for s, _ in shard_of])
        self._episode_steps += 1
        self._episode_steps[result.dones] = 0
        self._last = (result.obs, result.labels, result.privileged)
        return result

    def reset(self, mask: np.ndarray | None = None) -> StepResult:
        """Reset all envs or those selected by ``mask`` (bool [N]) on every shard.

        A shard lost meanwhile comes back with all its envs reset.
        """
        futures = [
            self._pool.submit(s.reset, None if mask is None else self._rows(np.asarray(mask), i))
            for i, s in enumerate(self.sessions)
        ]
        result = self._gather(futures, False, False)
        rows = slice(None) if mask is None else np.asarray(mask) != 0
        self._episode_steps[rows] = 0
        last = tuple(np.array(a) for a in self._last)  # only the reset rows are new
        for a, new in zip(last, (result.obs, result.labels, result.privileged), strict=True):
            a[rows] = new[rows]
        self._last = last
        return result

    def _replace(self, i: int, err: BaseException) -> StepResult:
        """Drop shard ``i``'s session, open one on the server ``reconnect`` names; its initial."""
        assert self._reconnect is not None
        while True:
            self._losses[i] += 1
            lost = self._clients[i].address
            if self._losses[i] > self._max_losses:
                raise ShardLostError(
                    f"shard {i}: server {lost} lost {self._max_losses} times in a row; last "
                    f"error: {err}"
                ) from err
            log.warning(
                "shard %d: server %s lost (%s: %s); recreating its session",
                i,
                lost,
                type(err).__name__,
                err,
            )
            self._drop(i)
            try:
                address = self._reconnect(i, lost)
                client = self._clients[i].connect_to(  # same TLS and token
                    address, connect_timeout_s=self._connect_timeout_s
                )
            except (UnigaitError, TimeoutError) as again:
                err = again
                continue
            self._clients[i], self._owned[i] = client, True
            self._generation[i] += 1
            try:
                session = client.create_session(self._shard_config(i))
            except UnigaitError as again:
                if not is_lost(again):
                    raise
                err = again
                continue
            self.sessions[i] = session
            self.server_restarts += 1
            log.warning(
                "shard %d: new session on %s (server restart %d); its %d episodes were cut and "
                "count as truncated",
                i,
                address,
                self.server_restarts,
                self.counts[i],
            )
            return session.initial

    def _drop(self, i: int) -> None:
        """Forget shard ``i``'s session without waiting on its (possibly vanished) server."""
        session, client = self.sessions[i], self._clients[i]
        if self._owned[i]:
            client.close()  # cancels the stream and any call still blocked on this channel
        else:  # the caller's channel: close the session in the background (bounded waits)
            threading.Thread(target=_close_quietly, args=(session,), daemon=True).start()

    def _cut(self, i: int, initial: StepResult, reward_terms: bool) -> StepResult:
        """Shard ``i``'s step result after its server was lost: every episode truncated."""
        n = self.counts[i]
        obs, labels, privileged = self._last
        with_terms = reward_terms or self._config.reward_terms
        return StepResult(
            obs=initial.obs,
            labels=initial.labels,
            privileged=initial.privileged,
            reward=np.zeros(n, dtype=np.float32),
            reward_terms=np.zeros((n, len(self.spec.reward_terms)), dtype=np.float32)
            if with_terms
            else None,
            terminated=np.zeros(n, dtype=bool),
            truncated=np.ones(n, dtype=bool),
            final_env_ids=np.arange(n, dtype=np.int64),
            final_obs=np.array(self._rows(obs, i)),
            final_labels=np.array(self._rows(labels, i)),
            final_privileged=np.array(self._rows(privileged, i)),
            final_episode_length=np.array(self._rows(self._episode_steps, i)),
            mode=initial.mode,
            terrain_level=initial.terrain_level,
            step_count=initial.step_count,
            nonfinite_resets=0,
            head_contact=np.zeros(n, dtype=bool),
            upright_pitch=initial.upright_pitch,
            mode_levels=initial.mode_levels,
        )

    def close(self) -> None:
        """Close every shard's session (and the clients this session owns)."""
        for s in self.sessions:
            try:
                s.close()
            except (UnigaitError, ValueError) as err:  # ValueError: a channel already closed
                if self._reconnect is None:
                    raise
                log.warning("closing session %s: %s", s.session_id, err)
        self.sessions = []
        self._pool.shutdown(wait=False)
        for c, owned in zip(self._clients, self._owned, strict=True):
            if owned:
                c.close()


def _poses_in_order(
    parts: Sequence[StepResult], local: Sequence[Sequence[int]], shards: Sequence[int]
) -> np.ndarray | None:
    """The shards' poses, rows back in the order asked (``shards``: each row's shard)."""
    rows: dict[int, Iterator[np.ndarray]] = {}
    for i, (part, asked) in enumerate(zip(parts, local, strict=True)):
        if not asked:
            continue
        if part.body_poses is None or len(part.body_poses) != len(asked):
            return None  # a shard replaced in this step returns none
        rows[i] = iter(part.body_poses)
    return np.stack([next(rows[s]) for s in shards])


def _close_quietly(session: Session) -> None:
    try:
        session.close()
    except Exception as err:  # a vanished server: nothing left to free
        log.debug("closing lost session %s: %s", session.session_id, err)


def open_session(
    addresses: str | Sequence[str],
    config: SessionConfig,
    *,
    connect_timeout_s: float = 10.0,
    reconnect: Reconnect | None = None,
    step_timeout_s: float | None = None,
    root_certificates: bytes | None = None,
    token: str | None = None,
    tls_server_name: str | None = None,
) -> Session | ShardedSession:
    """Connect and create a session; several addresses shard the batch across servers.

    Args:
        addresses: One ``host:port`` or several (also accepted: a comma-separated string).
        config: Session config; ``num_envs`` is the total over all servers.
        connect_timeout_s: Wait this long for each server.
        reconnect: Survive lost servers (see :class:`ShardedSession`); then even one address
            gives a :class:`ShardedSession`.
        step_timeout_s: With ``reconnect``: a server silent this long in a step counts as lost.
        root_certificates: PEM CA bundle for TLS, used for every server (see :class:`Client`;
            ``https://`` addresses mean TLS with the system roots without it).
        token: Bearer token sent to every server.
        tls_server_name: Certificate name to verify instead of each address's host.

    Returns:
        A :class:`Session` for one server, a :class:`ShardedSession` for several. Closing it
        closes the connections too.
    """
    if isinstance(addresses, str):
        addresses = [a.strip() for a in addresses.split(",") if a.strip()]
    if not addresses:
        raise ValueError("no server address given")
    clients: list[Client] = []
    try:
        for a in addresses:
            clients.append(
                Client(
                    a,
                    root_certificates=root_certificates,
                    token=token,
                    tls_server_name=tls_server_name,
                    connect_timeout_s=connect_timeout_s,
                )
            )
    except Exception:
        for c in clients:
            c.close()
        raise
    if len(clients) == 1 and reconnect is None:
        try:
            session = clients[0].create_session(config)
        except Exception:
            clients[0].close()
            raise
        session._owns_client = True
        return session
    return ShardedSession(
        clients,
        config,
        owns_clients=True,
        reconnect=reconnect,
        step_timeout_s=step_timeout_s,
        connect_timeout_s=connect_timeout_s,
    )
