"""``train --view`` against the real server: the drawn envs' robots come from the server.

A short run draws 3 envs every iteration into a saved recording; the robots are the server's
own drawing (the shapes of its recordings, entity for entity) posed every step.
"""

import tempfile
from pathlib import Path

import pytest
from unigait.cli import main
from unigait.client import Client, SessionConfig, open_session
from unigait.export import export_onnx, load_policy

rr = pytest.importorskip("rerun")
from rerun.experimental import RrdReader  # noqa: E402

SMALL = [
    "--set", "runner.num_steps_per_env=5",
    "--set", "policy.actor_hidden_dims=[16]",
    "--set", "policy.critic_hidden_dims=[16]",
    "--set", "estimator.hidden_dims=[16]",
    "--set", "estimator.mini_batch_size=8",
    "--set", "runner.save_interval=1",
    "--quiet",
]  # fmt: skip


def static_shapes(path: Path, root: str) -> dict[str, list[object]]:
    """Static chunks under ``root``: relative entity path -> their component columns."""
    out: dict[str, list[object]] = {}
    for chunk in RrdReader(path).stream():
        if chunk.is_static and chunk.entity_path.startswith(root + "/"):
            batch = chunk.to_record_batch()
            columns = {
                n: batch[n].to_pylist() for n in batch.schema.names if not n.startswith("rerun.")
            }
            out.setdefault(chunk.entity_path.removeprefix(root), []).append(columns)
    return {k: sorted(v, key=repr) for k, v in out.items()}


def test_a_run_draws_the_chosen_envs_as_the_servers_recordings_draw_robots(server, tmp_path):
    view = tmp_path / "view.rrd"
    run = tmp_path / "run"
    args = ["train", "--server", server, "--num-envs", "8", "--iterations", "2", *SMALL]
    args += ["--log-dir", str(run), "--view", "save", str(view)]
    assert main([*args, "--view-envs", "3", "--view-every", "1"]) == 0

    with open_session(server, SessionConfig(num_envs=1, robot_drawing=True)) as session:
        bodies = session.spec.body_names
    assert bodies[0] == "base" and len(bodies) > 10
    poses: dict[str, dict[int, list[float]]] = {}
    for chunk in RrdReader(view).stream():
        parts = chunk.entity_path.split("/")  # /world/envs/<slot>/robot/<body>
        if len(parts) == 6 and parts[2] == "envs" and not chunk.is_static:
            batch = chunk.to_record_batch()
            rows = batch["Transform3D:translation"].to_pylist()
            for step, t in zip(batch["step"].to_pylist(), rows, strict=True):
                poses.setdefault(f"{parts[3]}/{parts[5]}", {})[int(step)] = t[0]
    # Every body of the 3 slots, at each of the 2 x 5 steps.
    assert set(poses) == {f"{k}/{b}" for k in range(3) for b in bodies}
    assert all(sorted(p) == list(range(1, 11)) for p in poses.values())
    assert all(0.05 < p[2] < 0.8 for p in poses["0/base"].values())  # a standing robot's base

    # The shapes are the server's recordings' own, entity for entity: compare with a recording
    # the same server makes of an evaluation.
    policy, dims, _ = load_policy(run / "model_2.pt")
    with tempfile.TemporaryDirectory() as tmp:
        onnx = Path(tmp) / "p.onnx"
        export_onnx(policy, onnx, dims["history_length"], dims["obs_dim"])
        with Client(server) as client:
            result = client.evaluate(onnx.read_bytes(), "flat_quad", num_envs=1, record=True)
        recorded = Path(tmp) / "eval.rrd"
        recorded.write_bytes(result.recording_rrd)
        theirs = static_shapes(recorded, "/world/robot")
    ours = static_shapes(view, "/world/envs/0/robot")
    assert ours and ours == theirs


def test_sharded_sessions_return_poses_in_the_order_asked(server):
    import numpy as np
    from unigait.client import UnigaitError

    config = SessionConfig(num_envs=8, seed=4)
    zeros = np.zeros((8, 12), np.float32)
    with open_session([server, server], config) as a, open_session([server, server], config) as b:
        pa = a.step(zeros, draw_envs=[5, 1, 6]).body_poses
        pb = b.step(zeros, draw_envs=[1, 6, 5]).body_poses
        assert pa is not None and pb is not None and pa.shape == (3, len(a.spec.body_names), 7)
        np.testing.assert_array_equal(pa[[1, 2, 0]], pb)
        assert a.step(zeros).body_poses is None
        with pytest.raises(ValueError, match="draw_envs"):
            a.step(zeros, draw_envs=[8])
    with open_session(server, SessionConfig(num_envs=2)) as one, pytest.raises(UnigaitError):
        one.step(np.zeros((2, 12), np.float32), draw_envs=[2])
