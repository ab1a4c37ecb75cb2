"""The learner's loop, checkpoints, CSV/PNG output and export CLI over the fake session; rsl_rl's
own runner on the adapter."""

import csv
import dataclasses
import math
import tomllib

import pytest
import torch
from fakes import FAKE_UPRIGHT_PITCH, SMALL, FakeSession
from rsl_rl.runners import OnPolicyRunner as RslOnPolicyRunner

from unigait.cli import main, training_command
from unigait.config import load_config
from unigait.env import TorchVecEnv
from unigait.env.rsl_rl_env import RslRlVecEnv, rsl_rl_train_cfg
from unigait.milestones import milestone
from unigait.model_card import CardInputs, model_card
from unigait.runners import CheckpointMismatchError, NonFiniteUpdate, OnPolicyRunner
from unigait.storage import RolloutStorage


def test_runner_trains_logs_checkpoints_and_resumes(tmp_path, capsys):
    torch.manual_seed(0)
    cfg = load_config(None, SMALL)
    runner = OnPolicyRunner(TorchVecEnv(FakeSession(8)), cfg, tmp_path)
    before = [p.clone() for p in runner.estimator.parameters()]
    history = runner.learn(2)
    assert [h["iteration"] for h in history] == [1.0, 2.0]
    last = history[-1]
    shares = sum(last[f"time_share/{k}"] for k in ("simulation", "inference", "update"))
    assert 0.5 < shares <= 1.0 + 1e-6
    assert last["episodes"] > 0 and not math.isnan(last["mean_episode_reward"])
    assert "step_reward/quad_tracking_lin_vel" in last
    assert last["curriculum/upright_pitch"] == FAKE_UPRIGHT_PITCH  # as the session reports it
    assert runner.state_dict()["upright_pitch"] == FAKE_UPRIGHT_PITCH  # a resume starts there
    assert any(
        not torch.equal(a, b) for a, b in zip(before, runner.estimator.parameters(), strict=True)
    )
    assert "steps/s" in capsys.readouterr().out
    with (tmp_path / "progress.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 and "episode_reward/quad_tracking_lin_vel" in rows[0]
    assert (tmp_path / "training_curves.png").stat().st_size > 1000
    assert (tmp_path / "model_2.pt").is_file()

    resumed = OnPolicyRunner(TorchVecEnv(FakeSession(8)), cfg, tmp_path)
    resumed.load(tmp_path / "model_latest.pt")
    assert resumed.iteration == 2 and resumed.ppo.learning_rate == runner.ppo.learning_rate
    for a, b in zip(
        runner.actor_critic.parameters(), resumed.actor_critic.parameters(), strict=True
    ):
        assert torch.equal(a, b)
    resumed.learn(1)
    assert resumed.iteration == 3
    # Resumed from a checkpoint older than the log's last row: those rows go, not doubled.
    again = OnPolicyRunner(TorchVecEnv(FakeSession(8)), cfg, tmp_path)
    again.load(tmp_path / "model_2.pt")
    again.learn(1)
    with (tmp_path / "progress.csv").open() as f:
        assert [r["iteration"] for r in csv.DictReader(f)] == ["1", "2", "3"]
    # A fixed schedule resumes at the configured rate, not the checkpoint's.
    fixed_cfg = load_config(None, [*SMALL, "ppo.schedule=fixed", "ppo.learning_rate=3e-6"])
    fixed = OnPolicyRunner(TorchVecEnv(FakeSession(8)), fixed_cfg, tmp_path / "fixed")
    fixed.load(tmp_path / "model_2.pt")
    assert runner.ppo.learning_rate != 3e-6 and fixed.ppo.learning_rate == 3e-6
    assert all(g["lr"] == 3e-6 for g in fixed.ppo.optimizer.param_groups)
    # The estimator's rate is the configured one too (it has no schedule to carry).
    assert all(g["lr"] == 1e-4 for g in fixed.estimator_learning.optimizer.param_groups)
    slow_cfg = load_config(None, [*SMALL, "estimator.learning_rate=3e-6"])
    slow = OnPolicyRunner(TorchVecEnv(FakeSession(8)), slow_cfg, tmp_path / "slow")
    slow.load(tmp_path / "model_2.pt")
    assert all(g["lr"] == 3e-6 for g in slow.estimator_learning.optimizer.param_groups)

    # Staged training: networks and the adaptive learning rate, not the counters or optimiser;
    # the stage commands travel with the networks, and a resume adds none.
    first = training_command(["train", "--preset", "quad_flat", "--resume", "runs/q/m.pt"])
    assert first == "python -m unigait train --preset quad_flat"
    where = ["--server", "10.0.0.5:50051", "--tls-ca=/etc/ca.pem", "--token-file", "/run/t"]
    assert training_command(["train", *where, "--preset", "quad_flat"]) == first
    runner.record_stage(first)
    runner.ppo._set_lr(2.5e-5)
    runner.save(tmp_path / "model_staged.pt")
    continued = OnPolicyRunner(TorchVecEnv(FakeSession(8)), cfg, None)
    continued.load(tmp_path / "model_staged.pt")
    continued.record_stage(f"{first} --iterations 9000")  # resumed with another flag
    assert continued.stages == [first]
    # Resumed with other task overrides it trains another task: that is a stage. The upright
    # curriculum's start, which a resume sets from the checkpoint, is not.
    priced = "[rewards.weights]\nbiped_body_contact = -3.0\n"
    for fragment, stages in (
        ("[rewards.upright_curriculum]\nstart = 1.4\n", [first]),
        (priced, [first, f"{first} --set ... --resume {tmp_path / 'model_staged.pt'}"]),
    ):
        task = dataclasses.replace(cfg.env, task=tomllib.loads(fragment))
        changed = OnPolicyRunner(
            TorchVecEnv(FakeSession(8)), dataclasses.replace(cfg, env=task), None
        )
        changed.load(tmp_path / "model_staged.pt")
        changed.record_stage(f"{first} --set ...")
        assert changed.stages == stages, fragment
    # Another PPO setting trains the same task another way: a stage as well.
    lower_entropy = dataclasses.replace(cfg.ppo, entropy_coef=0.005)
    sharpened = OnPolicyRunner(
        TorchVecEnv(FakeSession(8)), dataclasses.replace(cfg, ppo=lower_entropy), None
    )
    sharpened.load(tmp_path / "model_staged.pt")
    sharpened.record_stage(f"{first} --set ppo.entropy_coef=0.005")
    assert sharpened.stages == [
        first,
        f"{first} --set ppo.entropy_coef=0.005 --resume {tmp_path / 'model_staged.pt'}",
    ]
    staged = OnPolicyRunner(TorchVecEnv(FakeSession(8)), cfg, None)
    staged.load_weights(tmp_path / "model_staged.pt")
    second = "python -m unigait train --preset unified_flat --init-from 'a b/model.pt'"
    staged.record_stage(second)
    staged.record_stage(second)
    assert staged.stages == [first, second]
    m2 = milestone("M2")

    def card_of(evals: dict, rows: list) -> str:
        return model_card(
            CardInputs(
                name="u",
                recipe="unified_flat",
                lineage="unified_flat_lineage",
                milestones=[m2],
                checkpoint=staged.state_dict(),
                evals=evals,
                rows=rows,
                commit="abc",
                eval_seed=1000,
                num_envs=8,
                ship_command="python -m unigait ship --run-dir r --name u --recipe unified_flat",
            )
        )

    card = card_of({}, [])
    assert "Biped mode" not in card  # no biped evaluation, no line
    assert "## Milestone M2: NOT met" in card and "| n/a | no |" in card
    biped_eval = {"tracking/biped/mean_pitch_rad": 0.5, "head_contact_share": 0.75}
    with_biped = card_of({"tracking_biped": biped_eval}, [])
    assert "mean pitch 0.50 rad (upright above 1.4), head on the ground 75% of the time." in (
        with_biped
    )
    assert "does nothing" not in with_biped  # an older server: no split, no table
    biped_eval["tracking/biped/lin_vel_error_lateral_mps"] = 0.125
    biped_eval["tracking/biped/do_nothing/lin_vel_error_lateral_mps"] = 0.25
    split = card_of({"tracking_biped": biped_eval}, [])
    assert "| biped | across the heading (m/s) | 0.125 | 0.250 |" in split
    switch = {
        "success_rate": 0.953125,
        "success_rate_ci95_low": 0.870,
        "success_rate_ci95_high": 0.984,
        "strict_success_rate": 0.5,
        "trials": 64,
    }
    # A further milestone's table shows its own checks; the repeated ones in one line.
    both = model_card(
        CardInputs(
            name="u",
            recipe="unified_flat",
            lineage=None,
            milestones=[m2, milestone("M2+")],
            checkpoint=staged.state_dict(),
            evals={
                "table_vi": {"stairs_up_biped/success_rate": 0.65, "stairs_up_biped/trials": 20}
            },
            rows=[],
            commit="a",
            eval_seed=1000,
            num_envs=8,
            ship_command="python -m unigait ship",
        )
    )
    plus = both.split("## Milestone M2+: NOT met")[1].split("##")[0]
    assert "Its checks of the tables above (M2): 0 of 7 met. Its own:" in plus
    assert plus.count("| no |") == 4
    assert "| 12 cm stairs up (b) | 0.6 | 0.65 | n/a | n/a | n/a | n/a | 20 |" in both
    strict = card_of({"transition_quad_to_biped": switch}, [])
    assert "| `transition_quad_to_biped` | 64 | 0.953 [0.87, 0.98] | 0.500 |" in strict
    # The wall time spans the shipped log alone, and the card says which iterations that is.
    log = [
        {"iteration": "41", "iteration_time_s": "1800"},
        {"iteration": "42", "iteration_time_s": "900"},
    ]
    logged = card_of({}, log)
    assert "training wall time: 0.75 h (iterations 41-42, the shipped log)" in logged
    assert "training wall time: 0.00 h\n" in card  # no log, no span
    reproduce = "python -m unigait train --recipe unified_flat --log-dir runs/unified_flat\n"
    assert f"```sh\n{reproduce}python -m unigait ship --run-dir r" in card
    assert "recipe `unified_flat_lineage` (the stages as they ran)" in card
    assert "- networks: actor [32, 16], critic [32, 16], estimator [16], elu: NOT Table III" in card
    assert staged.iteration == 0 and staged.ppo.learning_rate == 2.5e-5
    # Every difference named at once, each with its --set: sizes, activation, estimator.
    other = load_config(
        None,
        [
            *SMALL,
            "policy.actor_hidden_dims=[24, 16]",
            'policy.activation="tanh"',
            "estimator.hidden_dims=[8]",
        ],
    )
    mismatched = OnPolicyRunner(TorchVecEnv(FakeSession(8)), other, None)
    with pytest.raises(CheckpointMismatchError) as err:
        mismatched.load_weights(tmp_path / "model_staged.pt")
    message = str(err.value)
    assert "policy.actor_hidden_dims = [32, 16] (this run [24, 16])" in message
    assert "--set 'policy.actor_hidden_dims=[32, 16]'" in message
    assert "--set 'policy.activation=\"elu\"'" in message
    assert "--set 'estimator.hidden_dims=[16]'" in message
    assert "critic" not in message  # the same in both
    assert not staged.ppo.optimizer.state
    for a, b in zip(
        runner.actor_critic.parameters(), staged.actor_critic.parameters(), strict=True
    ):
        assert torch.equal(a, b)

    out = tmp_path / "policy.onnx"
    assert main(["export", "--checkpoint", str(tmp_path / "model_2.pt"), "--out", str(out)]) == 0
    assert "max |onnx - torch|" in capsys.readouterr().out


def test_rsl_rl_on_policy_runner_on_the_adapter():
    torch.manual_seed(0)
    env = RslRlVecEnv(TorchVecEnv(FakeSession(8)))
    cfg = rsl_rl_train_cfg(num_steps_per_env=6, hidden_dims=(32, 16))
    runner = RslOnPolicyRunner(env, cfg, log_dir=None, device="cpu")
    runner.learn(num_learning_iterations=2)
    assert runner.current_learning_iteration == 1


class Killed(BaseException):
    """The process dying mid-write (a BaseException, as SIGKILL would not be caught at all)."""


def test_a_kill_during_a_checkpoint_write_leaves_the_previous_checkpoint_whole(
    tmp_path, monkeypatch
):
    cfg = load_config(None, SMALL)
    runner = OnPolicyRunner(TorchVecEnv(FakeSession(8)), cfg, tmp_path)
    runner.learn(1)
    before = torch.load(tmp_path / "model_latest.pt", weights_only=False)
    real_save = torch.save

    def killed_half_way(obj: object, path: object) -> None:
        real_save(obj, path)
        if "model_latest" in str(path):  # dies while writing the latest checkpoint
            with open(path, "r+b") as f:  # what a kill mid-write leaves: a torn file
                f.truncate(100)
            raise Killed

    monkeypatch.setattr(torch, "save", killed_half_way)
    with pytest.raises(Killed):
        runner.learn(1)  # iteration 2's save is "killed"
    monkeypatch.undo()
    after = torch.load(tmp_path / "model_latest.pt", weights_only=False)
    assert after["iteration"] == before["iteration"] == 1


def test_the_rollout_extremes_name_the_largest_value_and_where_it_sits():
    st = RolloutStorage(3, 4, 6, 4, 5, 2, 2)
    for t in range(3):
        labels = torch.zeros(4, 2)
        actor = torch.ones(4, 6)
        if t == 1:
            labels[2, 1] = -7.5  # step 1, env 2, column 1
            actor[3, 4] = math.nan  # NaN counts as infinitely large
        st.add(
            actor,
            torch.zeros(4, 5),
            labels,
            torch.zeros(4, 2),
            torch.zeros(4),
            torch.zeros(4, 2),
            torch.ones(4, 2),
            torch.zeros(4),
            torch.zeros(4),
            torch.zeros(4),
        )
    largest = st.largest()
    assert largest["labels"] == (7.5, 1, 2, 1)
    assert largest["actor_obs"] == (math.inf, 1, 3, 4)
    assert largest["critic_obs"][0] == 0.0 and largest["mu"][0] == 0.0


class _LabelsGoInfinite(FakeSession):
    """Env 5's labels turn infinite from the third step on (a physics blow-up the server's
    finiteness check would not see in a finite but overflowing state)."""

    def step(self, actions, *, reward_terms=False):
        result = super().step(actions, reward_terms=reward_terms)
        if self.sim.step_count < 3:
            return result
        labels = result.labels.copy()
        labels[5, 0] = math.inf
        return dataclasses.replace(result, labels=labels)


def test_a_non_finite_rollout_stops_the_run_before_the_update(tmp_path):
    torch.manual_seed(0)
    cfg = load_config(None, SMALL)
    runner = OnPolicyRunner(TorchVecEnv(FakeSession(8)), cfg, tmp_path / "clean")
    row = runner.learn(1)[0]
    # The extremes go to the log with the column that holds each.
    assert row["rollout/max_abs/labels"] > 0 and "rollout/max_abs_column/actor_obs" in row
    assert row["rollout/max_abs/mu"] == max(
        abs(float(x)) for x in runner.storage.mu.flatten().tolist()
    )

    bad = OnPolicyRunner(TorchVecEnv(_LabelsGoInfinite(8)), cfg, tmp_path / "bad")
    before = [p.clone() for p in bad.actor_critic.parameters()]
    with pytest.raises(NonFiniteUpdate, match=r"labels inf at step \d+ env 5 column 0"):
        bad.learn(1)
    assert all(
        torch.equal(a, b) for a, b in zip(before, bad.actor_critic.parameters(), strict=True)
    )
    assert not list((tmp_path / "bad").glob("model_*.pt"))


class _BlowsUpEveryOtherStep(FakeSession):
    """The server reports one env reset for a physics blow-up on every second step."""

    def step(self, actions, *, reward_terms=False):
        result = super().step(actions, reward_terms=reward_terms)
        return dataclasses.replace(result, nonfinite_resets=self.sim.step_count % 2)


def test_the_log_counts_the_servers_blowup_resets(tmp_path):
    torch.manual_seed(0)
    cfg = load_config(None, SMALL)
    clean = OnPolicyRunner(TorchVecEnv(FakeSession(8)), cfg, tmp_path / "clean")
    assert clean.learn(1)[0]["physics_blowups"] == 0.0
    runner = OnPolicyRunner(TorchVecEnv(_BlowsUpEveryOtherStep(8)), cfg, tmp_path / "hit")
    steps = cfg.runner.num_steps_per_env
    rows = runner.learn(2)
    # Steps 1..2n of two rollouts: every odd one reports a reset.
    assert [r["physics_blowups"] for r in rows] == [steps // 2 + steps % 2, steps // 2]
