"""The gRPC client against an in-process fake server: stream, unary, reset, errors, sharding."""

import grpc
import numpy as np
import pytest
from fakes import FakeSession, start_fake_server

from unigait.client import (
    Client,
    ProtocolError,
    SessionConfig,
    ShardedSession,
    UnigaitError,
    open_session,
    split_envs,
)


def test_round_trip_stream_and_unary(fake_server):
    address, servicer = fake_server
    with Client(address) as client:
        info = client.server_info()
        assert info.server_version == "fake" and info.max_envs_per_session == 64
        session = client.create_session(SessionConfig(num_envs=4, seed=3))
        assert session.initial.obs.shape == (4, 53)
        assert session.spec.obs.slice("clock") == slice(47, 51)
        for k in range(1, 4):
            r = session.step(np.zeros((4, 12), np.float32))
            assert r.step_count == k
        r = session.step_unary(np.zeros((4, 12), np.float32))
        assert r.step_count == 4
        reset = session.reset(np.array([True, False, False, False]))
        assert reset.obs[0, 0] == 0.0  # age 0 after the reset
        session.close()
        assert servicer.sims == {}
        session.close()  # idempotent


def test_errors_carry_status_name_and_message(fake_server):
    address, _ = fake_server
    with Client(address) as client:
        session = client.create_session(SessionConfig(num_envs=4))
        with pytest.raises(UnigaitError) as err:
            session.step(np.zeros((4, 11), np.float32))
        assert err.value.code_name == "INVALID_ARGUMENT"
        assert err.value.code is grpc.StatusCode.INVALID_ARGUMENT
        assert "actions must be" in err.value.details
        # The stream is reopened after a failed step.
        assert session.step(np.zeros((4, 12), np.float32)).obs.shape == (4, 53)
        with pytest.raises(UnigaitError) as err:
            session.step_unary(np.zeros((3, 12), np.float32))
        assert err.value.code_name == "INVALID_ARGUMENT"
        session.close()
        with pytest.raises(UnigaitError) as err:
            session.step_unary(np.zeros((4, 12), np.float32))
        assert err.value.code_name == "NOT_FOUND"
        with pytest.raises(UnigaitError, match="INVALID_ARGUMENT"):
            client.create_session(SessionConfig(num_envs=1000))


def test_unreachable_server_is_unavailable():
    with pytest.raises(UnigaitError) as err:
        Client("127.0.0.1:1", connect_timeout_s=0.3)
    assert err.value.code_name == "UNAVAILABLE"


def test_split_envs():
    assert split_envs(10, 3) == [4, 3, 3]
    assert split_envs(4, 4) == [1, 1, 1, 1]
    with pytest.raises(ValueError):
        split_envs(1, 2)


def test_sharded_session_over_two_fake_servers():
    servers = [start_fake_server() for _ in range(2)]
    try:
        session = open_session([s[1] for s in servers], SessionConfig(num_envs=7, seed=10))
        assert isinstance(session, ShardedSession)
        assert session.counts == [4, 3] and session.offsets == [0, 4]
        assert session.spec.num_envs == 7
        # obs[:, 1] is the env index within its shard, obs[:, 2] the shard's seed.
        obs = session.initial.obs
        assert obs[:, 1].tolist() == [0, 1, 2, 3, 0, 1, 2]
        assert obs[:, 2].tolist() == [10] * 4 + [11] * 3
        reference = [FakeSession(4, 10), FakeSession(3, 11)]
        for _ in range(6):
            a = np.random.default_rng(0).standard_normal((7, 12)).astype(np.float32)
            r = session.step(a)
            parts = [reference[0].step(a[:4]), reference[1].step(a[4:])]
            np.testing.assert_array_equal(r.reward, np.concatenate([p.reward for p in parts]))
            expected_ids = np.concatenate([parts[0].final_env_ids, parts[1].final_env_ids + 4])
            np.testing.assert_array_equal(r.final_env_ids, expected_ids)
            np.testing.assert_array_equal(r.final_obs, np.concatenate([p.final_obs for p in parts]))
        mask = np.zeros(7, bool)
        mask[5] = True
        assert session.reset(mask).obs[5, 0] == 0.0
        session.close()
        assert all(not s[2].sims for s in servers)
    finally:
        for server, _, _ in servers:
            server.stop(grace=None)


def test_a_server_that_ignores_the_grid_columns_is_refused(fake_server):
    """The fake, like a server older than ``terrain.columns``, builds no grid of its own."""
    address, servicer = fake_server
    config = SessionConfig(num_envs=4, terrain="curriculum", terrain_columns=("slope_up",))
    with Client(address) as client:
        with pytest.raises(ProtocolError, match=r"predates TerrainConfig\.columns"):
            client.create_session(config)
        assert servicer.sims == {}  # the session it built was closed
    with pytest.raises(ProtocolError, match="slope_up"):
        open_session([address, address], config)
    assert servicer.sims == {}
