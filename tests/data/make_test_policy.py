"""Generate the small ONNX test policies of ``unigait-policy`` and their expected outputs.

No torch needed: the graphs are written with the ``onnx`` package's helper API and the expected
outputs come from an independent numpy forward pass of the same weights (cross-checked against
onnxruntime when it is installed). Everything is seeded, so running the script again writes the
same files::

    .venv/bin/python tests/data/make_test_policy.py            # the committed test files
    .venv/bin/python tests/data/make_test_policy.py --paper /tmp/paper_policy.onnx
                                                            # the paper-sized net (benchmarks)

Files written next to this script:

- ``test_policy.onnx``: the paper's fused estimator + actor structure, small hidden sizes
  (estimator [32, 16] -> 14, actor [32, 16] -> 12, ELU). Input ``obs_history`` f32
  ``[batch, 3, 53]`` (``batch`` is a ``dim_param``), output ``actions`` f32 ``[batch, 12]``.
- ``test_policy_fixed_batch.onnx``: the same weights with the batch fixed at 1 (as rsl_rl's
  exporter writes it).
- ``test_policy_wrong_width.onnx``: input ``[batch, 3, 50]``: must be refused.
- ``test_policy_expected.f32``: little-endian f32 ``[1024, 12]``, the numpy outputs for the
  inputs of :func:`history_inputs` (row 0 alone is the batch-1 case).
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OBS_DIM = 53
HISTORY = 3
LABEL_DIM = 14
NUM_ACTIONS = 12
HERE = Path(__file__).resolve().parent
EXPECTED_BATCH = 1024


def history_inputs(batch: int) -> np.ndarray:
    """Deterministic inputs ``[batch, 3, 53]`` by exact arithmetic (the Rust tests use the same).

    ``x[b, k] = ((b * 53 + k * 17) % 101) / 50 - 1`` with ``k`` the flat index within the row.
    """
    b = np.arange(batch, dtype=np.int64)[:, None]
    k = np.arange(HISTORY * OBS_DIM, dtype=np.int64)[None, :]
    x = ((b * 53 + k * 17) % 101).astype(np.float32) / np.float32(50.0) - np.float32(1.0)
    return x.reshape(batch, HISTORY, OBS_DIM)


def init_mlp(rng: np.random.Generator, sizes: list[int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Weights ``[out, in]`` (torch's Linear layout) and biases, uniform as torch initialises."""
    layers = []
    for fan_in, fan_out in itertools.pairwise(sizes):
        bound = 1.0 / np.sqrt(fan_in)
        w = rng.uniform(-bound, bound, size=(fan_out, fan_in)).astype(np.float32)
        b = rng.uniform(-bound, bound, size=(fan_out,)).astype(np.float32)
        layers.append((w, b))
    return layers


def elu(x: np.ndarray) -> np.ndarray:
    return np.where(x > 0, x, np.expm1(np.minimum(x, 0)))


def numpy_forward(
    estimator: list[tuple[np.ndarray, np.ndarray]],
    actor: list[tuple[np.ndarray, np.ndarray]],
    x: np.ndarray,
) -> np.ndarray:
    """The reference forward pass, in float64."""
    h = x.reshape(x.shape[0], -1).astype(np.float64)

    def mlp(layers: list[tuple[np.ndarray, np.ndarray]], v: np.ndarray) -> np.ndarray:
        for i, (w, b) in enumerate(layers):
            v = v @ w.astype(np.float64).T + b.astype(np.float64)
            if i + 1 < len(layers):
                v = elu(v)
        return v

    estimate = mlp(estimator, h)
    return mlp(actor, np.concatenate([h, estimate], axis=1)).astype(np.float32)


def build_graph(
    estimator: list[tuple[np.ndarray, np.ndarray]],
    actor: list[tuple[np.ndarray, np.ndarray]],
    batch: int | str,
    obs_dim: int = OBS_DIM,
) -> onnx.ModelProto:
    """Flatten -> estimator MLP -> concat(history, estimate) -> actor MLP, Gemm + Elu as torch."""
    nodes = [helper.make_node("Flatten", ["obs_history"], ["flat"], axis=1)]
    inits = []

    def mlp(prefix: str, layers: list[tuple[np.ndarray, np.ndarray]], x: str, out: str) -> None:
        for i, (w, b) in enumerate(layers):
            wn, bn = f"{prefix}.{i}.weight", f"{prefix}.{i}.bias"
            inits.append(numpy_helper.from_array(w, wn))
            inits.append(numpy_helper.from_array(b, bn))
            last = i + 1 == len(layers)
            y = out if last else f"{prefix}.{i}.linear"
            nodes.append(helper.make_node("Gemm", [x, wn, bn], [y], transB=1))
            if not last:
                act = f"{prefix}.{i}.elu"
                nodes.append(helper.make_node("Elu", [y], [act], alpha=1.0))
                x = act

    mlp("estimator", estimator, "flat", "estimate")
    nodes.append(helper.make_node("Concat", ["flat", "estimate"], ["actor_input"], axis=1))
    mlp("actor", actor, "actor_input", "actions")
    graph = helper.make_graph(
        nodes,
        "unigait_test_policy",
        [
            helper.make_tensor_value_info(
                "obs_history", TensorProto.FLOAT, [batch, HISTORY, obs_dim]
            )
        ],
        [helper.make_tensor_value_info("actions", TensorProto.FLOAT, [batch, NUM_ACTIONS])],
        inits,
    )
    model = helper.make_model(
        graph,
        producer_name="unigait make_test_policy.py",
        opset_imports=[helper.make_opsetid("", 17)],
    )
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model


def paper_weights(seed: int) -> tuple[list, list]:
    rng = np.random.default_rng(seed)
    obs = HISTORY * OBS_DIM
    estimator = init_mlp(rng, [obs, 256, 128, LABEL_DIM])
    actor = init_mlp(rng, [obs + LABEL_DIM, 512, 256, 128, NUM_ACTIONS])
    return estimator, actor


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paper", type=Path, help="write the paper-sized network here instead")
    args = parser.parse_args()
    if args.paper is not None:
        estimator, actor = paper_weights(seed=7)
        onnx.save(build_graph(estimator, actor, "batch"), args.paper)
        print(f"wrote {args.paper}")
        return

    rng = np.random.default_rng(20261122)
    obs = HISTORY * OBS_DIM
    estimator = init_mlp(rng, [obs, 32, 16, LABEL_DIM])
    actor = init_mlp(rng, [obs + LABEL_DIM, 32, 16, NUM_ACTIONS])
    onnx.save(build_graph(estimator, actor, "batch"), HERE / "test_policy.onnx")
    onnx.save(build_graph(estimator, actor, 1), HERE / "test_policy_fixed_batch.onnx")
    narrow = [(w[:, : HISTORY * 50], b) for (w, b) in estimator[:1]] + estimator[1:]
    narrow_actor = [(np.ascontiguousarray(actor[0][0][:, : HISTORY * 50 + LABEL_DIM]), actor[0][1])]
    narrow_actor += actor[1:]
    onnx.save(
        build_graph(narrow, narrow_actor, "batch", obs_dim=50),
        HERE / "test_policy_wrong_width.onnx",
    )

    x = history_inputs(EXPECTED_BATCH)
    expected = numpy_forward(estimator, actor, x)
    expected.astype("<f4").tofile(HERE / "test_policy_expected.f32")
    try:
        import onnxruntime as ort
    except ImportError:
        print("onnxruntime not installed: skipped the cross-check")
    else:
        session = ort.InferenceSession(str(HERE / "test_policy.onnx"))
        (got,) = session.run(None, {"obs_history": x})
        err = float(np.abs(got - expected).max())
        print(f"onnxruntime vs numpy: max abs difference {err:.3g}")
        assert err < 1e-5, err
    print(f"wrote test policies and {EXPECTED_BATCH}x{NUM_ACTIONS} expected outputs to {HERE}")


if __name__ == "__main__":
    main()
