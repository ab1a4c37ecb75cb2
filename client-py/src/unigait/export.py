"""Export the fused estimator + actor to ONE ONNX graph and check it against torch.

Graph: input ``obs_history`` f32 [batch, 3, 53] (o_t, o_{t-1}, o_{t-2}), output ``actions``
f32 [batch, 12] (the actor's mean), dynamic axis ``batch``. The model's metadata names the
physics engine the policy trained on (``unigait.physics_engine``), which the server evaluates it
on unless told otherwise (decision record 0026).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from unigait.config import TrainConfig, apply, checkpoint_engine
from unigait.modules import EstimatorActorPolicy
from unigait.runners.on_policy_runner import build_networks

#: ONNX opset of the export (tract-onnx and onnxruntime both run it).
OPSET = 17

#: The metadata key of the physics engine a policy trained on (the server reads it).
PHYSICS_ENGINE_KEY = "unigait.physics_engine"


def load_policy(checkpoint: str | Path) -> tuple[EstimatorActorPolicy, dict[str, int], str]:
    """The fused policy of a checkpoint (eval mode, CPU), its dims and its training engine."""
    state: dict[str, Any] = torch.load(checkpoint, map_location="cpu", weights_only=False)
    cfg = apply(TrainConfig(), state["config"])
    dims = state["dims"]
    actor_critic, estimator = build_networks(
        cfg, dims["obs_dim"], dims["label_dim"], dims["privileged_dim"], dims["num_actions"]
    )
    actor_critic.load_state_dict(state["actor_critic"])
    estimator.load_state_dict(state["estimator"])
    policy = EstimatorActorPolicy(estimator, actor_critic.actor).eval()
    return policy, dims, checkpoint_engine(state)


def export_onnx(
    policy: EstimatorActorPolicy,
    path: str | Path,
    history_length: int = 3,
    obs_dim: int = 53,
    *,
    physics_engine: str | None = None,
) -> None:
    """Write ``policy`` as ONNX (legacy TorchScript exporter, ``dynamo=False``).

    Stamped with the ``physics_engine`` it trained on, where given.
    """
    policy = policy.eval().to("cpu")
    dummy = torch.zeros(1, history_length, obs_dim)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", category=DeprecationWarning)
        warnings.simplefilter("ignore", category=FutureWarning)
        torch.onnx.export(
            policy,
            (dummy,),
            str(path),
            input_names=["obs_history"],
            output_names=["actions"],
            dynamic_axes={"obs_history": {0: "batch"}, "actions": {0: "batch"}},
            opset_version=OPSET,
            dynamo=False,
        )
    if physics_engine:
        out = Path(path)
        out.write_bytes(with_metadata(out.read_bytes(), PHYSICS_ENGINE_KEY, physics_engine))


def with_metadata(onnx: bytes, key: str, value: str) -> bytes:
    """``onnx`` with one more ``ModelProto.metadata_props`` entry (field 14).

    A repeated field may be appended to a serialised message, so the graph's bytes stay as they
    were (and no ``onnx`` package is needed to write it).
    """
    entry = _length_delimited(1, key.encode()) + _length_delimited(2, value.encode())
    return onnx + _length_delimited(14, entry)


def _length_delimited(field: int, payload: bytes) -> bytes:
    return _varint(field << 3 | 2) + _varint(len(payload)) + payload


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        low, n = n & 0x7F, n >> 7
        out.append(low | (0x80 if n else 0))
        if not n:
            return bytes(out)


def export_mismatch(
    policy: EstimatorActorPolicy, path: str | Path, batch: int = 64, seed: int = 0
) -> float:
    """Largest |onnxruntime - torch| over a random batch, relative to the actions' scale.

    The batch is f32 [batch, H, 53] of N(0, 1) values; the difference is divided by
    max(1, max |torch|).

    Relative because float32 rounding grows with the size of the outputs: on N(0, 1) inputs a
    trained policy's actions reach ~10, where 1e-5 absolute is one part in a million.

    Raises:
        ImportError: onnxruntime is not installed (it is in the ``dev`` extra).
    """
    import onnxruntime

    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    shape = session.get_inputs()[0].shape
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((batch, int(shape[1]), int(shape[2]))).astype(np.float32)
    (onnx_out,) = session.run(["actions"], {"obs_history": x})
    with torch.no_grad():
        torch_out = policy(torch.from_numpy(x)).numpy()
    scale = max(1.0, float(np.max(np.abs(torch_out))))
    return float(np.max(np.abs(onnx_out - torch_out))) / scale
