"""A two-stage recipe on the real server, killed in the middle of its second stage: the same
command carries on there and ends with the same stages and iterations as an uninterrupted run."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

RECIPE = """
description = "two tiny stages on the real server"

[[stages]]
name = "first"
[stages.stop]
iterations = 3
[stages.env]
num_envs = 8
[stages.policy]
actor_hidden_dims = [16]
critic_hidden_dims = [16]
[stages.estimator]
hidden_dims = [16]
mini_batch_size = 8
[stages.runner]
num_steps_per_env = 4
save_interval = 1
plot_interval = 1000
quiet = true
[stages.task.rewards.weights]
biped_body_contact = -3.0

[[stages]]
name = "second"
start = "previous"
carry = "all"
[stages.stop]
iterations = 150
[stages.ppo]
entropy_coef = 0.0025
"""


def _iterations(stage: Path) -> list[int]:
    with (stage / "progress.csv").open() as f:
        return [int(float(row["iteration"])) for row in csv.DictReader(f)]


def test_a_recipe_killed_in_its_second_stage_resumes_there(server, server_bin, tmp_path):
    recipe = tmp_path / "tiny.toml"
    recipe.write_text(RECIPE)
    run = tmp_path / "run"
    command = [sys.executable, "-m", "unigait", "train", "--server", server]
    command += ["--recipe", str(recipe), "--log-dir", str(run)]
    env = {**os.environ, "UNIGAIT_SERVER_BIN": str(server_bin)}
    second = run / "02_second"
    child = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        # Kill it once the second stage has saved a few checkpoints of its own (stage 1 ends at
        # iteration 3; the second stage counts on from there).
        deadline = time.monotonic() + 120
        while not (second / "model_6.pt").exists():
            assert child.poll() is None, child.stderr.read() if child.stderr else ""
            assert time.monotonic() < deadline, "the second stage never got going"
            time.sleep(0.05)
        child.send_signal(signal.SIGKILL)
        child.wait(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
    assert (run / "01_first" / "done.json").exists()
    assert not (second / "done.json").exists(), "killed too late: the stage had ended"
    killed_at = max(_iterations(second))
    assert 6 <= killed_at < 153

    resumed = subprocess.run(command, env=env, capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    assert "stage 01_first: ended before" in resumed.stderr
    assert "stage 02_second: resumed at iteration" in resumed.stderr
    stages = sorted(p.name for p in run.iterdir() if p.is_dir())
    assert stages == ["01_first", "02_second"]
    done = json.loads((second / "done.json").read_text())
    assert done["final_checkpoint"] == "model_153.pt" and done["stage_iterations"] == 150
    # The log has every iteration of the stage once: rows past the resumed checkpoint dropped.
    assert _iterations(second) == list(range(4, 154))
    assert (run / "final.pt").is_file()
