"""The Rust learner's runs ship like the Python learner's (issue 38): ``python -m unigait ship``
chooses among ``model_<it>.ckpt`` checkpoints, exports through ``unigait-learner export``, has
the real server evaluate the policy, and writes a card that says which learner reproduces it.
"""

from __future__ import annotations

import csv
import json
import math
import subprocess

import pytest
from unigait.checkpoints import CheckpointError, read_checkpoint
from unigait.cli import main

RECIPE = """
description = "two iterations of quad_flat, a checkpoint each"
milestone = "M1"

[[stages]]
name = "quad"
start = "fresh"

[stages.stop]
iterations = 2

[stages.env]
num_envs = 8
terrain = "flat"

[stages.task.modes]
biped_probability = 0.0

[stages.runner]
save_interval = 1
quiet = true
"""


def test_a_rust_learner_run_ships_and_the_server_evaluates_it(
    server, server_bin, learner_bin, tmp_path, monkeypatch
):
    recipe = tmp_path / "quad_two.toml"
    recipe.write_text(RECIPE)
    run = tmp_path / "run"
    train = ["train", "--server", server, "--recipe", str(recipe), "--log-dir", str(run)]
    done = subprocess.run(
        [str(learner_bin), *train, "--seed", "3", "--tensorboard"],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    stage = run / "01_quad"
    assert (stage / "model_1.ckpt").is_file() and (stage / "model_2.ckpt").is_file()
    # --tensorboard: TensorBoard's own reader finds the CSV's names, step = iteration.
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    (event_file,) = stage.glob("events.out.tfevents.*")
    events = EventAccumulator(str(event_file))
    events.Reload()
    with (stage / "progress.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert set(events.Tags()["scalars"]) == set(rows[0])
    kl = {e.step: e.value for e in events.Scalars("kl")}
    assert kl.keys() == {1, 2}
    for row in rows:
        assert math.isclose(kl[int(row["iteration"])], float(row["kl"]), rel_tol=1e-5)
    header = read_checkpoint(stage / "model_2.ckpt")
    assert header["iteration"] == 2 and header["total_env_steps"] == 2 * 8 * 24
    assert header["config"]["env"]["num_envs"] == 8
    assert header["provenance"]["learner"].startswith("unigait-learner")
    # The recipe leaves the engine to the server: its default, which the checkpoint records.
    assert header["physics_engine"] == "articulated"

    monkeypatch.setenv("UNIGAIT_LEARNER_BIN", str(learner_bin))
    out = tmp_path / "policies"
    ship = ["ship", "--server", server, "--run-dir", str(run), "--recipe", "quad_flat"]
    ship += ["--name", "rs", "--out-root", str(out), "--num-envs", "4"]
    assert main([*ship, "--select-last", "2", "--select-envs", "4"]) == 0
    folder = out / "rs"
    assert (folder / "model.ckpt").read_bytes() in {
        (stage / "model_1.ckpt").read_bytes(),
        (stage / "model_2.ckpt").read_bytes(),
    }
    assert not (folder / "model.pt").exists()
    onnx = (folder / "policy.onnx").read_bytes()
    assert onnx[:2] == b"\x08\x08"  # ModelProto.ir_version = 8: a graph, not an error page
    assert b"unigait.physics_engine\x12\x0barticulated" in onnx  # its metadata entry
    evals = json.loads((folder / "eval.json").read_text())
    quad = evals["tracking_quad"]
    # Two iterations do not walk, and the server measured it: a real figure, not a default.
    assert 0.0 < quad["tracking/quad/lin_vel_error_mps"] < 5.0
    card = (folder / "MODEL_CARD.md").read_text()
    assert "unigait-learner train --recipe quad_flat --log-dir runs/quad_flat" in card
    assert "no GPU (unigait-learner, burn on the CPU)" in card
    assert "on the `articulated` physics engine" in card
    assert "Chosen among the run's last 2 checkpoints" in card


def test_a_file_that_is_not_a_rust_checkpoint_is_named(tmp_path):
    bad = tmp_path / "model_5.ckpt"
    bad.write_bytes(b"UGLCKPT0" + bytes(8))
    with pytest.raises(CheckpointError, match=r"model_5\.ckpt: not a unigait-learner checkpoint"):
        read_checkpoint(bad)
    bad.write_bytes(b"UGLCKPT1" + (5).to_bytes(8, "little") + b"{nope")
    with pytest.raises(CheckpointError, match="the header is not JSON"):
        read_checkpoint(bad)
