"""Servers as Ray actors on a real local two-node Ray cluster (loopback only): placement over
nodes, training over the pool, a server killed mid-run, and no stray server processes."""

import json
import logging
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

# Every Ray process of the test cluster binds 127.0.0.1 (read when ray is imported).
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
ray = pytest.importorskip("ray", reason="the ray extra is not installed")

from ray.cluster_utils import Cluster  # noqa: E402
from unigait.cli import main  # noqa: E402
from unigait.client import Client  # noqa: E402
from unigait.config import load_config  # noqa: E402
from unigait.env import TorchVecEnv  # noqa: E402
from unigait.ray import ResilientRunner, ServerPool, train_with_pool  # noqa: E402
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


def _servers_of(binary: Path) -> set[int]:
    """Pids of live ``BINARY serve`` processes on this machine."""
    found = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            argv = (entry / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if argv[0] == str(binary).encode() and b"serve" in argv[1:2] and _running(int(entry.name)):
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
    assert_all_gone(pids)
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
    before = _servers_of(server_bin)
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
    while _servers_of(server_bin) - before and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _servers_of(server_bin) - before, "the CLI left server processes behind"
