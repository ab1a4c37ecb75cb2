"""Servers as Ray actors on a real local two-node Ray cluster (loopback only): placement over
nodes, training over the pool, a server killed mid-run, no stray server processes, and servers
with TLS and a bearer token.

Leak checks look only at servers the pools started (their pids, or ``$UNIGAIT_RAY_POOL`` in their
environment), never at other ``unigait-server`` processes on the machine (a training run, another
test session)."""

import json
import logging
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

# Every Ray process of the test cluster binds 127.0.0.1 (read when ray is imported).
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
ray = pytest.importorskip("ray", reason="the ray extra is not installed")

from ray.cluster_utils import Cluster  # noqa: E402
from unigait.cli import main  # noqa: E402
from unigait.client import Client, UnigaitError  # noqa: E402
from unigait.config import load_config  # noqa: E402
from unigait.env import TorchVecEnv  # noqa: E402
from unigait.ray import (  # noqa: E402
    PoolConfigError,
    ResilientRunner,
    ServerCredentials,
    ServerPool,
    train_with_pool,
)
from unigait.ray.server_actor import POOL_ID_ENV  # noqa: E402
from unigait.ray.train import session_config  # noqa: E402

NUM_ENVS = 32
STEPS = 8  # per env and iteration: 2 iterations = 16 steps


@pytest.fixture(scope="module")
def cluster():
    """A head and a worker node on this machine, 2 logical CPUs each; the driver connected."""
    node = {"num_cpus": 2, "include_dashboard": False, "object_store_memory": 80 * 1024**2}
    c = Cluster(initialize_head=True, connect=True, head_node_args=node)
    c.add_node(**{k: v for k, v in node.items() if k != "include_dashboard"})
    c.wait_for_nodes()
    yield c
    ray.shutdown()
    c.shutdown()


def tiny_config(log_dir: Path, *extra: str):
    return load_config(
        None,
        [
            f"env.num_envs={NUM_ENVS}",
            "runner.max_iterations=2",
            f"runner.num_steps_per_env={STEPS}",
            f"runner.log_dir={json.dumps(str(log_dir))}",
            "runner.quiet=true",
            "runner.update_threads=1",
            "policy.actor_hidden_dims=[32]",
            "policy.critic_hidden_dims=[32]",
            "estimator.hidden_dims=[32]",
            "ppo.num_learning_epochs=1",
            *extra,
        ],
    )


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False
    return state != "Z"


def pool_servers(pool_id: str | None = None) -> set[int]:
    """Pids of live servers started by a Ray pool (by ``pool_id``; None: by any pool).

    A pool's actors put ``$UNIGAIT_RAY_POOL`` into their servers' environment, so servers
    started any other way (a training run sharing the machine) are never counted.
    """
    marker = f"{POOL_ID_ENV}=".encode()
    found = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            env = (entry / "environ").read_bytes().split(b"\0")
        except OSError:  # gone, or not ours to read
            continue
        ids = [v[len(marker) :].decode() for v in env if v.startswith(marker)]
        if ids and (pool_id is None or ids[0] == pool_id) and _running(int(entry.name)):
            found.add(int(entry.name))
    return found


def assert_all_gone(pids: set[int], timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while any(_running(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [p for p in pids if _running(p)], "server processes outlived the pool"


def active_sessions(address: str) -> int:
    with Client(address) as client:
        return client.server_info().active_sessions


def test_two_servers_on_two_nodes_train_two_iterations(cluster, server_bin, tmp_path):
    with ServerPool(2, 1, binary=str(server_bin)) as pool:
        nodes = {m.node_id for m in pool.members}
        assert len(nodes) == 2, f"both servers on one node: {pool.members}"
        assert all(m.address.startswith("127.0.0.1:") for m in pool.members)
        history = train_with_pool(pool, tiny_config(tmp_path))
        assert [h["iteration"] for h in history] == [1.0, 2.0]
        assert history[-1]["server_restarts"] == 0 and pool.restarts == [0, 0]
        assert history[-1]["total_env_steps"] == 2 * STEPS * NUM_ENVS
        assert [active_sessions(a) for a in pool.addresses] == [0, 0]
        pids = set(pool.pids_seen)
        assert pool_servers(pool.pool_id) == pids  # the marker finds exactly the pool's servers
    assert_all_gone(pids)
    assert not pool_servers(pool.pool_id)
    assert (tmp_path / "progress.csv").read_text().splitlines()[0].count("server_restarts") == 1


def test_killed_server_is_replaced_and_its_episodes_truncated(
    cluster, server_bin, tmp_path, caplog
):
    caplog.set_level(logging.WARNING)
    kill_at = STEPS + 3  # a step in the second iteration
    with ServerPool(2, 1, binary=str(server_bin), restart_timeout_s=90) as pool:
        victim = pool.members[1]
        session = pool.open_session(session_config(tiny_config(tmp_path)))
        lo, hi = session.offsets[1], session.offsets[1] + session.counts[1]
        results = [session.initial]
        plain_step = session.step

        def step(actions, **kwargs):
            if len(results) == kill_at:
                os.kill(victim.pid, signal.SIGKILL)
            results.append(plain_step(actions, **kwargs))
            return results[-1]

        session.step = step
        env = TorchVecEnv(session)
        try:
            history = ResilientRunner(env, tiny_config(tmp_path), tmp_path).learn(2)
            # While the run is open: one session on each server, none left on the lost one's
            # survivor or duplicated on the replacement.
            assert pool.addresses[0] == session.addresses[0]
            assert pool.addresses[1] == session.addresses[1] != victim.address
            assert [active_sessions(a) for a in pool.addresses] == [1, 1]
        finally:
            env.close()
        assert [active_sessions(a) for a in pool.addresses] == [0, 0]
        assert pool.restarts == [0, 1] and session.server_restarts == 1
        assert pool.members[1].pid != victim.pid
        pids = set(pool.pids_seen)
    assert_all_gone(pids)

    assert len(results) == 2 * STEPS + 1  # the run finished
    assert [h["server_restarts"] for h in history] == [0.0, 1.0]
    cut, before = results[kill_at], results[kill_at - 1]
    assert cut.truncated[lo:hi].all() and not cut.terminated[lo:hi].any()
    ended = list(cut.final_env_ids)
    rows = [ended.index(e) for e in range(lo, hi)]
    np.testing.assert_array_equal(cut.final_obs[rows], before.obs[lo:hi])
    np.testing.assert_array_equal(cut.final_privileged[rows], before.privileged[lo:hi])
    assert (cut.reward[lo:hi] == 0).all()
    assert history[1]["time_outs"] >= hi - lo  # counted as time-outs, bootstrapped
    assert f"shard 1: server {victim.address} lost" in caplog.text
    assert "server 1 restarted" in caplog.text
    assert "count as truncated" in caplog.text


def test_silent_server_times_out_and_is_restarted(cluster, server_bin, caplog):
    """A server that stops answering (SIGSTOP: a hung process, or a node cut off without a
    connection reset) costs its shard a step timeout, then its actor is restarted."""
    caplog.set_level(logging.WARNING)
    with ServerPool(2, 1, binary=str(server_bin), hung_timeout_s=2) as pool:
        frozen = pool.members[1]
        config = session_config(tiny_config(Path("unused")))
        session = pool.open_session(config, step_timeout_s=2)
        actions = np.zeros((NUM_ENVS, 12), np.float32)
        try:
            session.step(actions)
            os.kill(frozen.pid, signal.SIGSTOP)
            started = time.monotonic()
            cut = session.step(actions)
            waited = time.monotonic() - started
            lo = session.offsets[1]
            assert cut.truncated[lo:].all() and not cut.truncated[:lo].any()
            assert session.server_restarts == 1 and pool.restarts == [0, 1]
            assert session.step(actions).obs.shape == (NUM_ENVS, 53)
        finally:
            if _running(frozen.pid):
                os.kill(frozen.pid, signal.SIGCONT)
            session.close()
        assert 2 <= waited < 30
        assert "has not answered the health check" in caplog.text
        pids = set(pool.pids_seen)
    assert_all_gone(pids)


def test_missing_binary_fails_fast_and_names_the_path(cluster, tmp_path):
    missing = tmp_path / "no-such-server"
    pool = ServerPool(1, 1, binary=str(missing), max_restarts=0)
    with pytest.raises(ray.exceptions.RayActorError, match="no executable unigait server"):
        pool.start()
    assert not pool.members


def test_cli_train_ray_leaves_no_servers(cluster, server_bin, tmp_path, capsys):
    before = pool_servers()
    code = main(
        [
            "train",
            "--ray",
            cluster.address,
            "--servers",
            "2",
            "--cpus-per-server",
            "1",
            "--num-envs",
            str(NUM_ENVS),
            "--iterations",
            "2",
            "--log-dir",
            str(tmp_path),
            "--quiet",
            "--set",
            f"env.server_bin={json.dumps(str(server_bin))}",
            "--set",
            f"runner.num_steps_per_env={STEPS}",
            "--set",
            "policy.actor_hidden_dims=[32]",
            "--set",
            "policy.critic_hidden_dims=[32]",
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "2 Ray server actor(s)" in out and out.count("server 0: 127.0.0.1:") == 1
    rows = (tmp_path / "progress.csv").read_text().splitlines()
    assert len(rows) == 3 and "server_restarts" in rows[0]
    deadline = time.monotonic() + 20
    while pool_servers() - before and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not pool_servers() - before, "the CLI left server processes behind"


# --- TLS and a bearer token -------------------------------------------------------------------

TOKEN = "t0ken-for-the-ray-pool-test"


def _self_signed(cert: Path, key: Path, name: str, san: str) -> None:
    """A self-signed server certificate (openssl, valid one day), as tests/test_tls_client.py."""
    subprocess.run(
        [
            *("openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1"),
            *("-subj", f"/CN={name}", "-addext", f"subjectAltName={san}"),
            *("-addext", "basicConstraints=critical,CA:FALSE"),
            *("-addext", "extendedKeyUsage=serverAuth", "-keyout", str(key), "-out", str(cert)),
        ],
        check=True,
        capture_output=True,
    )


@pytest.fixture(scope="module")
def tls_files(tmp_path_factory):
    """A self-signed certificate for localhost and 127.0.0.1 (its own CA), key, token file."""
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is needed to make a test certificate")
    directory = tmp_path_factory.mktemp("ray-tls")
    cert, key = directory / "cert.pem", directory / "key.pem"
    _self_signed(cert, key, "localhost", "DNS:localhost,IP:127.0.0.1")
    token_file = directory / "token"
    token_file.write_text(TOKEN + "\n")
    return cert, key, token_file


def _server_argv(pid: int) -> list[str]:
    return [a.decode() for a in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0") if a]


def test_tls_token_pool_trains_and_restarts_over_tls(cluster, server_bin, tls_files, tmp_path):
    """Credentials shipped in the actors' arguments: the servers speak TLS and check the token,
    the learner trains two iterations over them, and a killed server comes back with them."""
    cert, key, _ = tls_files
    credentials = ServerCredentials.shipped(cert, key, TOKEN)
    assert TOKEN not in repr(credentials)  # no secret in logs
    with ServerPool(2, 1, binary=str(server_bin), credentials=credentials) as pool:
        assert len({m.node_id for m in pool.members}) == 2
        for m in pool.members:
            argv = _server_argv(m.pid)
            assert "--tls-cert" in argv and "--token-file" in argv
            # Shipped contents come through pipes, never a file.
            for flag in ("--tls-cert", "--tls-key", "--token-file"):
                assert argv[argv.index(flag) + 1].startswith("/dev/fd/"), argv
        with pytest.raises(UnigaitError, match="plaintext"):  # TLS only
            Client(pool.addresses[0], token=TOKEN, connect_timeout_s=1.5)
        with Client(pool.addresses[0], root_certificates=cert.read_bytes()) as client:
            with pytest.raises(UnigaitError) as err:  # TLS without the token
                client.server_info()
            assert err.value.code_name == "UNAUTHENTICATED"

        history = train_with_pool(pool, tiny_config(tmp_path))
        assert [h["iteration"] for h in history] == [1.0, 2.0]
        assert history[-1]["total_env_steps"] == 2 * STEPS * NUM_ENVS

        # A lost server: the restarted actor gets the credentials again, the shard reconnects
        # over TLS with the token, and health checks work over TLS.
        session = pool.open_session(session_config(tiny_config(tmp_path)))
        actions = np.zeros((NUM_ENVS, 12), np.float32)
        try:
            session.step(actions)
            victim = pool.members[1]
            os.kill(victim.pid, signal.SIGKILL)
            cut = session.step(actions)
            assert cut.truncated[session.offsets[1] :].all()
            assert session.server_restarts == 1 and pool.restarts == [0, 1]
            assert "--tls-key" in _server_argv(pool.members[1].pid)
            assert session.step(actions).obs.shape == (NUM_ENVS, 53)
        finally:
            session.close()
        pids = set(pool.pids_seen)
    assert_all_gone(pids)


def test_wrong_or_missing_token_fails_fast_with_the_servers_answer(cluster, server_bin, tls_files):
    """Servers whose token is a file on the nodes; a learner with another token, or none, is
    refused at the pool's start, in seconds, naming the cause."""
    cert, key, token_file = tls_files
    node_files = {"cert_file": str(cert), "key_file": str(key), "token_file": str(token_file)}
    for token, expected in (
        ("a-wrong-token-of-enough-length", "wrong bearer token"),
        (None, "needs `authorization: Bearer"),
    ):
        credentials = ServerCredentials(**node_files, token=token, ca=cert.read_bytes())
        pool = ServerPool(1, 1, binary=str(server_bin), credentials=credentials)
        started = time.monotonic()
        with pytest.raises(PermissionError, match=expected) as err:
            pool.start()
        assert time.monotonic() - started < 30
        assert "server 0" in str(err.value) and "token" in str(err.value)
        assert_all_gone(set(pool.pids_seen))


def test_untrusted_certificate_fails_fast(cluster, server_bin, tls_files, tmp_path):
    cert, key, _ = tls_files
    other = tmp_path / "other.pem"
    _self_signed(other, tmp_path / "other.key", "other", "DNS:other")
    credentials = ServerCredentials(
        cert_file=str(cert), key_file=str(key), token=TOKEN, ca=other.read_bytes()
    )
    pool = ServerPool(1, 1, binary=str(server_bin), credentials=credentials)
    started = time.monotonic()
    with pytest.raises(ConnectionError, match="CERTIFICATE_VERIFY_FAILED"):
        pool.start()
    assert time.monotonic() - started < 30
    assert_all_gone(set(pool.pids_seen))


def test_servers_beyond_loopback_need_tls_and_a_token():
    with pytest.raises(PoolConfigError, match="requires TLS and a bearer token"):
        ServerPool(1, 1, host=None)  # each node's IP
    with pytest.raises(PoolConfigError, match="requires TLS and a bearer token"):
        ServerPool(1, 1, host="0.0.0.0", credentials=ServerCredentials(token=TOKEN))
    with pytest.raises(ValueError, match="at least 16"):
        ServerCredentials(token="short")
    with pytest.raises(ValueError, match="CA"):
        ServerCredentials(cert_file="/c", key_file="/k", token=TOKEN)  # nothing to verify with
    with pytest.raises(ValueError, match="go together"):
        ServerCredentials(cert_pem=b"PEM", token=TOKEN)


def test_cli_train_ray_over_tls_with_token_from_the_environment(
    cluster, server_bin, tls_files, tmp_path, capsys, monkeypatch
):
    """train --ray with the servers' certificate and key as paths on the nodes, the learner's
    CA (--tls-ca) and $UNIGAIT_TOKEN (shipped to the servers); without the token: refused."""
    cert, key, _ = tls_files
    argv = [
        "train",
        "--ray",
        cluster.address,
        "--servers",
        "2",
        "--num-envs",
        str(NUM_ENVS),
        "--iterations",
        "1",
        "--quiet",
        "--tls-ca",
        str(cert),
        "--server-tls-cert",
        str(cert),
        "--server-tls-key",
        str(key),
        "--set",
        f"env.server_bin={json.dumps(str(server_bin))}",
        "--set",
        f"runner.num_steps_per_env={STEPS}",
        "--set",
        "policy.actor_hidden_dims=[32]",
        "--set",
        "policy.critic_hidden_dims=[32]",
    ]
    before = pool_servers()
    monkeypatch.setenv("UNIGAIT_TOKEN", TOKEN)
    assert main([*argv, "--log-dir", str(tmp_path / "ok")]) == 0
    out = capsys.readouterr().out
    assert out.count("TLS + token") == 2 and "2 Ray server actor(s)" in out
    assert len((tmp_path / "ok" / "progress.csv").read_text().splitlines()) == 2

    # Servers with a token file on the nodes, a learner without a token: a clear refusal.
    monkeypatch.delenv("UNIGAIT_TOKEN")
    token_file = tls_files[2]
    code = main([*argv, "--server-token-file", str(token_file), "--log-dir", str(tmp_path / "no")])
    assert code == 2
    err = capsys.readouterr().err
    assert "refused the learner, which sent no token" in err
    deadline = time.monotonic() + 20
    while pool_servers() - before and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not pool_servers() - before, "the CLI left server processes behind"


# --- secrets never kept by Ray or left on a node ----------------------------------------------


def _memory_holds(pid: int, needles: list[bytes]) -> dict[bytes, bool]:
    """Which of ``needles`` appear in the writable memory of process ``pid`` (read as root)."""
    found = dict.fromkeys(needles, False)
    chunk, overlap = 16 << 20, max(len(n) for n in needles)
    with open(f"/proc/{pid}/maps") as maps, open(f"/proc/{pid}/mem", "rb", 0) as mem:
        for line in maps:
            span, perms = line.split()[:2]
            if not perms.startswith("rw"):
                continue
            start, end = (int(x, 16) for x in span.split("-"))
            for at in range(start, end, chunk):
                try:
                    mem.seek(at)
                    data = mem.read(min(chunk + overlap, end - at))
                except (OSError, OverflowError, ValueError):  # unreadable (guard pages, vvar)
                    break
                for n in needles:
                    found[n] = found[n] or n in data
    return found


def test_the_token_is_not_kept_by_rays_control_store(cluster, server_bin, tls_files):
    """Ray keeps every actor's creation arguments in its control store (the GCS process) for
    restarts. The pool's id, a creation argument, is found in the GCS's memory (so the search
    can see them); the shipped token and key, sent in the start call instead, are not."""
    if os.geteuid() != 0:
        pytest.skip("reading another process's memory needs root")
    cert, key, _ = tls_files
    gcs = cluster.head_node.all_processes["gcs_server"][0].process.pid
    key_body = key.read_bytes().splitlines()[5]  # a line of the key's base64
    credentials = ServerCredentials.shipped(cert, key, TOKEN)
    with ServerPool(2, 1, binary=str(server_bin), credentials=credentials) as pool:
        with Client(pool.addresses[0], root_certificates=cert.read_bytes(), token=TOKEN) as client:
            assert client.server_info().active_sessions == 0  # the servers got the token
        found = _memory_holds(gcs, [pool.pool_id.encode(), TOKEN.encode(), key_body])
    assert found[pool.pool_id.encode()], "the search does not see creation arguments"
    assert not found[TOKEN.encode()], "the token is in Ray's control store"
    assert not found[key_body], "the private key is in Ray's control store"


def test_an_actor_killed_while_its_server_starts_leaves_no_secret_behind(
    cluster, tls_files, tmp_path
):
    """Kill an actor while its server is starting (a stand-in server that reads its token file
    and hangs): the token reached the server, and nothing under /dev/shm holds it or the key,
    then or after the kill."""
    from unigait.ray.server_actor import ServerActor

    cert, key, _ = tls_files
    fake = tmp_path / "hanging-server"
    fake.write_text(
        "#!/bin/sh\n"
        'while [ $# -gt 0 ]; do [ "$1" = --token-file ] && cat "$2" > "$0.read"; shift; done\n'
        "while :; do sleep 1; done\n"
    )
    fake.chmod(0o755)
    got = Path(f"{fake}.read")
    secrets = [TOKEN.encode(), key.read_bytes().splitlines()[5]]

    def shm_holding_secrets() -> list[Path]:
        hits = []
        for p in Path("/dev/shm").rglob("*"):
            try:
                if p.is_file() and p.stat().st_size < (1 << 20):
                    data = p.read_bytes()
                    hits += [p] if any(s in data for s in secrets) else []
            except OSError:
                continue
        return hits

    before = {p.name for p in Path("/dev/shm").iterdir()}
    actor = (
        ray.remote(ServerActor)
        .options(num_cpus=0, max_restarts=0)
        .remote(str(fake), 1, "127.0.0.1", (), 60.0)
    )
    starting = actor.start.remote(ServerCredentials.shipped(cert, key, TOKEN))
    deadline = time.monotonic() + 30
    while not (got.exists() and got.read_text() == TOKEN) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert got.read_text() == TOKEN, "the stand-in server never read its token"
    hanging = [
        int(e.name)
        for e in Path("/proc").iterdir()
        if e.name.isdigit() and _running(int(e.name)) and str(fake).encode() in _cmdline(e)
    ]
    assert hanging, "the stand-in server is not running"
    argv = _server_argv(hanging[0])
    assert argv[argv.index("--token-file") + 1].startswith("/dev/fd/") and TOKEN not in argv
    assert not shm_holding_secrets(), "secrets written to /dev/shm during the start"
    ray.kill(actor, no_restart=True)
    with pytest.raises(ray.exceptions.RayActorError):
        ray.get(starting, timeout=30)
    assert_all_gone(set(hanging))
    new = {p.name for p in Path("/dev/shm").iterdir()} - before
    assert not [n for n in new if n.startswith("unigait-credentials")], new
    assert not shm_holding_secrets(), "secrets left in /dev/shm by the killed actor"


def _cmdline(entry: Path) -> bytes:
    try:
        return (entry / "cmdline").read_bytes()
    except OSError:
        return b""
