"""Tensor packing, the typed Spec and StepResult decoding (no server)."""

import numpy as np
import pytest
from fakes import REWARD_TERMS, FakeSession, FakeSim, proto_spec, to_proto

from unigait.client import ProtocolError, Spec, StepResult
from unigait.client.proto import pb
from unigait.client.tensors import decode, encode


def test_tensor_round_trip_is_zero_copy():
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    t = encode(a)
    assert list(t.shape) == [3, 4] and t.dtype == pb.DTYPE_F32 and len(t.data) == 48
    b = decode(t)
    np.testing.assert_array_equal(a, b)
    assert not b.flags.writeable  # a view of the message's bytes, not a copy
    u = decode(encode(np.array([1, 0, 1]), "u1"))
    assert u.dtype == np.uint8 and u.tolist() == [1, 0, 1]


def test_tensor_size_mismatch_and_absent_tensor():
    bad = pb.Tensor(shape=[2, 3], dtype=pb.DTYPE_F32, data=b"\0" * 20)
    with pytest.raises(ProtocolError, match="needs 24 bytes"):
        decode(bad)
    assert decode(pb.Tensor(), (53,)).shape == (0, 53)


def test_spec_slices_by_name():
    spec = Spec.from_proto(proto_spec(8))
    assert spec.obs_dim == 53 and spec.label_dim == 14 and spec.privileged_dim == 10
    assert spec.obs.slice("clock") == slice(47, 51)
    assert spec.obs.slice("q") == slice(9, 21)
    assert spec.labels.slice("foot_height") == slice(10, 14)
    assert spec.reward_term_index("quad_tracking_lin_vel") == 10
    assert spec.num_actions == 12 and spec.autoreset == "SAME_STEP"
    assert spec.episode_length_s == pytest.approx(0.1)
    with pytest.raises(KeyError, match="clock"):
        spec.obs.slice("nope")


def test_step_result_decoding_and_concat():
    spec = Spec.from_proto(proto_spec(4))
    sim = FakeSim(4)
    r = StepResult.from_proto(to_proto(sim.step(np.zeros((4, 12), np.float32)), 1), spec)
    assert r.obs.shape == (4, 53) and r.reward_terms.shape == (4, len(REWARD_TERMS))
    assert r.terminated.dtype == bool and r.final_env_ids.dtype == np.int64
    assert r.final_obs.shape == (len(r.final_env_ids), 53)
    assert r.dones.sum() == len(r.final_env_ids)

    # Envs of a 5-env fake start at ages 0..4: env 4 times out on the first step.
    parts = [FakeSession(5).step(np.zeros((5, 12))) for _ in range(2)]
    assert parts[0].final_env_ids.tolist() == [4]
    joined = StepResult.concat(parts, [0, 5])
    assert joined.obs.shape == (10, 53)
    assert joined.final_env_ids.tolist() == [4, 9]
    assert joined.final_obs.shape == (2, 53)


def test_initial_result_without_reward_fills_defaults():
    spec = Spec.from_proto(proto_spec(3))
    msg = to_proto({"obs": np.zeros((3, 53), np.float32)})
    r = StepResult.from_proto(msg, spec)
    assert r.reward.shape == (3,) and r.terminated.shape == (3,) and r.reward_terms is None
    assert r.final_obs.shape == (0, 53) and r.final_labels.shape == (0, 14)
