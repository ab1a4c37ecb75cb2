"""The chance of meeting a milestone on an unseen draw, against hand-computed cases."""

import math

import pytest
from test_milestones import M2_MET

from unigait.milestones import Check, milestone
from unigait.pass_chance import (
    at_least,
    check_chance,
    draw_chance,
    milestone_chance,
    trials_metric,
)

ALL = Check("s", "success_rate", ">=", 1.0, "every trial")
MOST = Check("s", "success_rate", ">=", 0.6, "12 of 20")
FEW_FALLS = Check("s", "fall_rate", "<=", 0.05, "at most 1 of 20")


def every_one_of(n: int, successes: float, trials: float) -> float:
    """P(n of n) under Beta(s + 1/2, f + 1/2): the product of the posterior's successive means."""
    a, b = successes + 0.5, trials - successes + 0.5
    return math.prod((a + i) / (a + b + i) for i in range(n))


def test_trials_sit_beside_each_success_rate():
    assert trials_metric("stairs_up_quad/success_rate") == "stairs_up_quad/trials"
    assert trials_metric("success_rate") == "trials"
    assert trials_metric("strict_success_rate") == "trials"
    assert trials_metric("tracking/quad/lin_vel_error_mps") is None


def test_a_draw_of_one_or_two_is_the_posterior_predictive():
    # 3 of 4 seen: the posterior Beta(3.5, 1.5) has mean 0.7.
    assert draw_chance(ALL, 3, 4, 1) == pytest.approx(0.7)
    assert draw_chance(ALL, 3, 4, 2) == pytest.approx(3.5 * 4.5 / (5 * 6))
    assert draw_chance(ALL, 128, 128, 20) == pytest.approx(every_one_of(20, 128, 128))
    assert draw_chance(ALL, 125, 128, 20) == pytest.approx(every_one_of(20, 125, 128))
    # A perfect record of 128 still leaves a few per cent for a miss in 20.
    assert 0.9 < draw_chance(ALL, 128, 128, 20) < 0.95


def test_many_trials_approach_the_binomial_tail():
    tail = sum(math.comb(20, x) for x in range(12, 21)) / 2**20  # 12 or more of 20 at 0.5
    assert draw_chance(MOST, 500_000, 1_000_000, 20) == pytest.approx(tail, abs=1e-3)
    # A bound from above: at most one fall in 20 at a rate of 0.05.
    at_most_one = 0.95**20 + 20 * 0.05 * 0.95**19
    assert draw_chance(FEW_FALLS, 50_000, 1_000_000, 20) == pytest.approx(at_most_one, abs=1e-3)


def test_at_least_k_of_independent_events():
    assert at_least([0.5, 0.5], 1) == pytest.approx(0.75)
    assert at_least([0.5, 0.5], 2) == pytest.approx(0.25)
    assert at_least([1.0, 1.0, 0.9, 0.5], 3) == pytest.approx(1 - 0.1 * 0.5)
    assert at_least([0.3], 0) == pytest.approx(1.0)
    assert at_least([0.3, 0.4], 3) == 0.0


def test_a_check_pools_its_seeds_and_a_mean_counts_the_seeds_that_met_it():
    seeds = [{"s": {"success_rate": 1.0, "trials": 64}}, {"s": {"success_rate": 0.5, "trials": 64}}]
    assert check_chance(ALL, seeds, 20) == pytest.approx(every_one_of(20, 96, 128))
    error = Check("s", "error", "<=", 0.2, "an error")
    means = [{"s": {"error": 0.1}}, {"s": {"error": 0.3}}]
    assert check_chance(error, means, 64) == 0.5
    # A rate without its trial count is judged as a mean; a missing figure is not met.
    assert check_chance(ALL, [{"s": {"success_rate": 1.0}}, {"s": {}}], 20) == 0.5


def test_m3_multiplies_its_checks_and_takes_4_of_tables_vi_6():
    m3 = milestone("M3")
    switch = {"success_rate": 1.0, "trials": 64}
    flat = {**M2_MET, "transition_biped_to_quad": switch, "transition_quad_to_biped": switch}
    crossed = {"stairs_up_quad": 128, "stairs_down_quad": 128, "slope_quad": 128}
    crossed |= {"slope_biped": 100, "stairs_up_biped": 40, "stairs_down_biped": 127}
    table_vi = {}
    for column, n in crossed.items():
        table_vi[f"{column}/success_rate"] = n / 128
        table_vi[f"{column}/trials"] = 128.0
    seed = {**flat, "table_vi": table_vi}
    draw = {s: m3.envs_for(s, 64) for s in m3.scenarios}
    assert draw["table_vi"] == 20 and draw["tracking_quad"] == 64
    # Two seeds alike: every count doubles.
    switches = draw_chance(Check("t", "success_rate", ">=", 0.9, "t"), 128, 128, 64) ** 2
    columns = [
        every_one_of(20, 256, 256),
        every_one_of(20, 256, 256),
        every_one_of(20, 256, 256),
        every_one_of(20, 200, 256),
        draw_chance(MOST, 80, 256, 20),
        every_one_of(20, 254, 256),
    ]
    expected = switches * at_least(columns, 4)
    assert milestone_chance(m3, [seed, seed], draw) == pytest.approx(expected)
    # One seed's quad yaw-rate error over its bound halves the chance.
    worse = {**flat["tracking_quad"], "tracking/quad/ang_vel_error_radps": 0.3}
    other = {**seed, "tracking_quad": worse}
    assert milestone_chance(m3, [seed, other], draw) == pytest.approx(expected / 2)
    with pytest.raises(ValueError, match="at least one seed"):
        milestone_chance(m3, [], draw)


def test_the_cli_reads_reports_by_seed_and_prints_each_checks_chance(tmp_path, capsys):
    import json

    from unigait.cli import main

    def report(seed: int, scenario: str, metrics: dict[str, float]) -> str:
        path = tmp_path / f"{scenario}_{seed}.json"
        path.write_text(json.dumps({"scenario": scenario, "seed": seed, "metrics": metrics}))
        return str(path)

    track = {"tracking/biped/upright_share": 1.0, "tracking/biped/lin_vel_error_mps": 0.1}
    reports = [
        report(seed, "tracking_biped", {**track, "tracking/biped/lin_vel_error_mps": error})
        for seed, error in ((5, 0.1), (6, 0.3))
    ]
    assert main(["pass-chance", "--milestone", "M2-biped", *reports]) == 0
    out = capsys.readouterr().out
    assert "M2-biped on one unseen draw, from seeds 5, 6" in out
    assert "| biped upright share >= 0.9 | 1, 1 | 64 | 1.000 |" in out
    assert "| biped lin. vel. error <= 0.2 | 0.1, 0.3 | 64 | 0.500 |" in out
    assert "chance of meeting M2-biped: 0.500" in out
    # A success rate shows its trials; the draw is the milestone's size for Table VI.
    transition = report(5, "transition_biped_to_quad", {"success_rate": 1.0, "trials": 128})
    others = [
        report(5, "tracking_quad", {"tracking/quad/termination_rate": 0.0}),
        report(5, "transition_quad_to_biped", {"success_rate": 1.0, "trials": 128}),
        report(5, "table_vi", {"stairs_up_quad/success_rate": 1.0, "stairs_up_quad/trials": 128}),
    ]
    assert main(["pass-chance", reports[0], transition, *others, "--num-envs", "32"]) == 0
    out = capsys.readouterr().out
    assert "| biped -> quad success >= 0.9 | 1 (128 trials) | 32 |" in out
    chance = every_one_of(20, 128, 128)
    assert f"| 15 cm stairs up (q) [table_vi] >= 1 | 1 (128 trials) | 20 | {chance:.3f} |" in out
    # Missing scenarios, a report twice and a file that is not a report are refused.
    assert main(["pass-chance", reports[0]]) == 2
    assert "seed 5 has no report of tracking_quad" in capsys.readouterr().err
    assert main(["pass-chance", reports[0], reports[0]]) == 2
    assert "a second tracking_biped report for seed 5" in capsys.readouterr().err
    (tmp_path / "x.json").write_text("[]")
    assert main(["pass-chance", str(tmp_path / "x.json")]) == 2
    assert "x.json: not an evaluation report" in capsys.readouterr().err
    assert main(["pass-chance", "--milestone", "M9", reports[0]]) == 2
    assert "unknown milestone 'M9'" in capsys.readouterr().err
