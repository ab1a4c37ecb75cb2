"""Choosing the checkpoint to ship on a validation seed: the score, the candidates, the CLI."""

import csv

import pytest
from test_cli import SMALL

from unigait.cli import main
from unigait.milestones import milestone
from unigait.selection import Candidate, SeedScore, describe, rank, recent_checkpoints


def test_milestone_score_counts_criteria_and_sums_clipped_relative_margins():
    evals = {
        "tracking_quad": {
            "tracking/quad/lin_vel_error_mps": 0.12,  # <= 0.15: met, margin +0.2
            "tracking/quad/ang_vel_error_radps": 0.3,  # <= 0.2: not met, -0.5
            "tracking/quad/termination_rate": 0.0,  # <= 0.05: met, +1.0
        },
        "tracking_biped": {
            "tracking/biped/upright_share": 0.99,  # >= 0.9: met, +0.1
            "tracking/biped/lin_vel_error_mps": 0.6,  # <= 0.2: not met, -2 clipped to -1
        },
        "transition_biped_to_quad": {"success_rate": 1.0},  # >= 0.9: met, +1/9
        # transition_quad_to_biped missing: not met, -1
    }
    met, margin = milestone("M2").score(evals)
    assert met == 4
    assert margin == pytest.approx(0.2 - 0.5 + 1.0 + 0.1 - 1.0 + 0.1 / 0.9 - 1.0)


def test_recent_checkpoints_are_the_highest_iterations_in_order(tmp_path):
    for name in ("model_25.pt", "model_100.pt", "model_50.pt", "model_latest.pt", "model_7x.pt"):
        (tmp_path / name).write_bytes(b"")
    assert [i for i, _ in recent_checkpoints(tmp_path, 2)] == [50, 100]
    assert [p.name for _, p in recent_checkpoints(tmp_path, 9)] == [
        "model_25.pt",
        "model_50.pt",
        "model_100.pt",
    ]
    assert recent_checkpoints(tmp_path, 0) == []


def test_rank_puts_seeds_fully_met_before_criteria_summed_over_seeds(tmp_path):
    def candidate(iteration: int, *scores: tuple[int, float]) -> Candidate:
        per_seed = tuple(SeedScore(2000 + i, m, g) for i, (m, g) in enumerate(scores))
        return Candidate(tmp_path / f"model_{iteration}.pt", iteration, per_seed)

    lucky = candidate(100, (8, 2.0), (6, 0.5))  # 14 criteria, met on one seed
    steady = candidate(200, (7, 1.0), (7, 1.0))  # 14 criteria, on neither
    confirmed = candidate(300, (8, 0.1), (8, 0.1))  # both seeds
    close = candidate(400, (8, 1.9), (6, 0.6))  # as lucky, a larger margin
    ranked = rank([lucky, steady, confirmed, close], criteria=8)
    assert [c.iteration for c in ranked] == [300, 400, 100, 200]
    assert (confirmed.met, confirmed.margin, confirmed.seeds_met(8)) == (16, 0.2, 2)
    text = describe(ranked, milestone("M3"), 20)
    assert "on validation seeds 2000 + 2001 (20 envs per scenario)" in text
    assert "100: 8/8 + 6/8 (+2.50), 200: 7/8 + 7/8 (+2.00), 300: 8/8 + 8/8 (+0.20)" in text
    assert "Iteration 300 ranked first" in text


def test_ship_chooses_on_the_validation_seed_and_reports_on_the_evaluation_seed(
    fake_server, tmp_path, capsys
):
    address, servicer = fake_server
    run = tmp_path / "run"
    train = ["train", "--server", address, "--num-envs", "6", "--log-dir", str(run), *SMALL]
    engine = 'env.task.physics.engine="articulated"'
    assert main([*train, "--iterations", "3", "--set", engine]) == 0
    ship = ["ship", "--server", address, "--run-dir", str(run), "--recipe", "unified_flat"]
    ship += ["--name", "u", "--out-root", str(tmp_path / "policies"), "--num-envs", "4"]
    servicer.evaluated.clear()
    servicer.evaluated_overrides.clear()
    select = ["--select-last", "2", "--select-seed", "7", "--select-envs", "12"]
    assert main([*ship, *select, "--eval-seed", "1000"]) == 0
    scenarios = list(milestone("M2").scenarios)
    # Iterations 2 and 3 on seed 7 with 12 envs, then the chosen one on seed 1000 with 4.
    assert servicer.evaluated == [(s, 7, 12) for s in scenarios] * 2 + [
        (s, 1000, 4) for s in scenarios
    ]
    # Chosen and judged on the engine it trained on, which the card names.
    assert set(servicer.evaluated_overrides) == {'physics.engine = "articulated"'}
    card = (tmp_path / "policies" / "u" / "MODEL_CARD.md").read_text()
    assert "on the `articulated` physics engine" in card
    # The fake server's figures are the same for both: the later checkpoint wins the tie.
    assert "last 2 checkpoints on validation seed 7 (12 envs per scenario)" in card
    assert "2: 0/7 (-7.00), 3: 0/7 (-7.00). Iteration 3 ranked first" in card
    # Two validation seeds: every candidate on each, then the chosen one on the evaluation seed.
    servicer.evaluated.clear()
    two = ["--select-last", "2", "--select-seed", "7", "--select-seed", "8"]
    assert main([*ship, *two, "--eval-seed", "1000"]) == 0
    assert servicer.evaluated == (
        [(s, 7, 4) for s in scenarios] + [(s, 8, 4) for s in scenarios]
    ) * 2 + [(s, 1000, 4) for s in scenarios]
    card = (tmp_path / "policies" / "u" / "MODEL_CARD.md").read_text()
    assert "on validation seeds 7 + 8 (4 envs per scenario)" in card
    assert "2: 0/7 + 0/7 (-14.00), 3: 0/7 + 0/7 (-14.00)" in card
    folder = tmp_path / "policies" / "u"
    # Every scenario's full report is in the folder; reports made beside ship stay with the
    # checkpoint they describe.
    assert sorted(p.name for p in (folder / "reports").iterdir()) == sorted(
        f"{s}_seed1000.json" for s in scenarios
    )
    (folder / "reports" / "table_vi_seed1000.json").write_text("{}")
    assert main([*ship, "--checkpoint", str(run / "model_3.pt")]) == 0  # the same checkpoint
    assert (folder / "reports" / "table_vi_seed1000.json").exists()
    # An earlier checkpoint ships with the log up to it, not the run's later rows.
    assert main([*ship, "--checkpoint", str(run / "model_2.pt")]) == 0
    assert not (folder / "reports" / "table_vi_seed1000.json").exists()
    with (folder / "progress.csv").open() as f:
        assert [int(float(r["iteration"])) for r in csv.DictReader(f)] == [1, 2]
    assert (folder / "training.png").stat().st_size > 0
    assert not (folder / "training_curves.png").exists()
    assert "(iterations 1-2, the shipped log)" in (folder / "MODEL_CARD.md").read_text()
    # Ranked by the pass chance: the card says so.
    servicer.evaluated.clear()
    by_chance = ["--select-last", "1", "--select-seed", "7", "--select-by", "pass-chance"]
    assert main([*ship, *by_chance, "--select-envs", "12"]) == 0
    assert servicer.evaluated[: len(scenarios)] == [(s, 7, 12) for s in scenarios]
    card = (folder / "MODEL_CARD.md").read_text()
    assert "by the estimated chance of meeting M2 on one unseen draw" in card
    assert "from 12 envs per scenario on validation seed 7" in card
    capsys.readouterr()
    # The validation seed must not be the evaluation seed, and a given checkpoint is not chosen.
    assert main([*ship, "--select-last", "2", "--select-seed", "1000"]) == 2
    assert main([*ship, "--select-last", "2", "--select-seed", "7", "--select-seed", "1000"]) == 2
    assert main([*ship, "--select-last", "2", "--checkpoint", str(run / "model_2.pt")]) == 2
    assert "--select-last chooses the checkpoint" in capsys.readouterr().err


def test_pass_chance_ranks_on_many_trials_of_every_scenario(fake_server, tmp_path):
    from test_pass_chance import every_one_of

    from unigait.checkpoints import export_policy
    from unigait.milestones import Check, Milestone
    from unigait.selection import select_checkpoint

    address, servicer = fake_server
    run = tmp_path / "run"
    train = ["train", "--server", address, "--num-envs", "6", "--log-dir", str(run), *SMALL]
    assert main([*train, "--iterations", "3"]) == 0
    # Every trial crossed for iteration 2, 0.9 of them for iteration 3, nothing for 1.
    for iteration, rate in ((2, 1.0), (3, 0.9)):
        export_policy(run / f"model_{iteration}.pt", tmp_path / "p.onnx")
        servicer.policy_success[(tmp_path / "p.onnx").read_bytes()] = rate
    # Judged on 20 trials; chosen on 12 a seed.
    check = Check("course", "success_rate", ">=", 1.0, "every trial")
    judged = Milestone("T", "test", ("course", "flat"), (check,), {}, {"course": 20})
    servicer.evaluated.clear()
    ranked = select_checkpoint(run, judged, address, 3, [7, 8], 12, by="pass_chance")
    assert servicer.evaluated == [(s, seed, 12) for seed in (7, 8) for s in ("course", "flat")] * 3
    assert [c.iteration for c in ranked] == [2, 3, 1]
    # 24 of 24 seen, and 22 of 24 (0.9 of 12 rounds to 11 a seed).
    assert ranked[0].chance == pytest.approx(every_one_of(20, 24, 24))
    assert ranked[1].chance == pytest.approx(every_one_of(20, 22, 24))
    assert ranked[2].chance == 0.0
    text = describe(ranked, judged, 12)
    assert "by the estimated chance of meeting T on one unseen draw" in text
    assert "from 12 envs per scenario on validation seeds 7 + 8" in text
    assert f"1: 0.00, 2: {ranked[0].chance:.2f}, 3: {ranked[1].chance:.2f}" in text
    assert "Iteration 2 ranked first" in text
    # By criteria the course is judged on the milestone's own 20 trials.
    servicer.evaluated.clear()
    select_checkpoint(run, judged, address, 1, [7], 12)
    assert servicer.evaluated == [("course", 7, 20), ("flat", 7, 12)]
    with pytest.raises(ValueError, match="unknown ranking"):
        select_checkpoint(run, judged, address, 1, [7], 12, by="luck")
