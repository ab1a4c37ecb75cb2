"""Milestones as data: the packaged file, extends, groups, fixed trial counts and errors."""

import pytest

from unigait.milestones import MilestoneError, load_milestones, milestone, parse_milestones

TABLE_VI = {
    "stairs_up_quad": 1.0,
    "stairs_down_quad": 1.0,
    "slope_quad": 1.0,
    "slope_biped": 1.0,
    "stairs_up_biped": 0.6,
    "stairs_down_biped": 1.0,
}


def test_the_packaged_milestones_extend_each_other():
    known = load_milestones()
    assert set(known) == {"M1", "M2", "M2-biped", "M2+", "M3"}
    m1, m2, m2p, m3 = (known[n] for n in ("M1", "M2", "M2+", "M3"))
    # The two-policy baseline's biped is held to M2's two-legged checks, no more.
    biped = known["M2-biped"]
    assert biped.scenarios == ("tracking_biped",)
    assert biped.checks == tuple(c for c in m2.checks if c.scenario == "tracking_biped")
    assert m2.checks[: len(m1.checks)] == m1.checks and len(m2.checks) == 7
    assert m2p.checks[:7] == m2.checks and len(m2p.checks) == 11
    assert m2p.scenarios == m2.scenarios  # M2+ needs no scenario M2 does not run
    assert m3.scenarios == (*m2.scenarios, "table_vi") and m3.envs_for("table_vi", 64) == 20
    assert m2.envs_for("tracking_biped", 64) == 64
    # M3's Table VI checks are the paper's figures, grouped: 4 of 6 must pass.
    assert {c.metric.split("/")[0]: c.bound for c in m3.checks if c.group} == TABLE_VI
    assert m3.criteria() == 7 + 1


#: Flat-ground figures that meet every M2 check.
M2_MET = {
    "tracking_quad": {
        "tracking/quad/lin_vel_error_mps": 0.1,
        "tracking/quad/ang_vel_error_radps": 0.1,
        "tracking/quad/termination_rate": 0.0,
    },
    "tracking_biped": {
        "tracking/biped/upright_share": 1.0,
        "tracking/biped/lin_vel_error_mps": 0.1,
    },
    "transition_biped_to_quad": {"success_rate": 1.0},
    "transition_quad_to_biped": {"success_rate": 1.0},
}


def test_a_group_passes_with_enough_of_its_checks():
    m3 = milestone("M3")
    flat = dict(M2_MET)
    columns = {f"{k}/success_rate": v for k, v in TABLE_VI.items()}
    # Three columns short: 3 of 6 pass, the group (and so M3) is not met.
    three = {**columns, "stairs_up_quad/success_rate": 0.9, "slope_quad/success_rate": 0.5}
    three["stairs_up_biped/success_rate"] = 0.55
    assert m3.score({**flat, "table_vi": three})[0] == 7 and not m3.met({**flat, "table_vi": three})
    # What falls short is said with its figures.
    assert m3.unmet({**flat, "table_vi": three}) == [
        "table_vi: 3 of 6, needs 4: 15 cm stairs up (q) 0.9 (needs >= 1); "
        "30 deg slope (q) 0.5 (needs >= 1); 12 cm stairs up (b) 0.55 (needs >= 0.6)"
    ]
    slow = {**flat["tracking_quad"], "tracking/quad/ang_vel_error_radps": 0.226}
    assert m3.unmet({**flat, "tracking_quad": slow, "table_vi": three})[0] == (
        "quad yaw-rate error 0.226 (needs <= 0.2)"
    )
    assert m3.unmet({"table_vi": columns})[0] == "quad lin. vel. error missing (needs <= 0.15)"
    four = {**three, "stairs_up_biped/success_rate": 0.6}
    assert m3.met({**flat, "table_vi": four}) and m3.unmet({**flat, "table_vi": four}) == []


@pytest.mark.parametrize(
    ("doc", "says"),
    [
        ({"A": {"scenarios": ["s"], "checkz": []}}, "unknown key(s) ['checkz']"),
        ({"A": {"extends": "B"}}, "no milestone [B]"),
        ({"A": {"extends": "A"}}, "extends itself"),
        (
            {
                "A": {
                    "scenarios": ["s"],
                    "checks": [
                        {"label": "x", "scenario": "t", "metric": "m", "op": "<=", "bound": 1}
                    ],
                }
            },
            "checks scenario 't', not in its scenarios",
        ),
        (
            {
                "A": {
                    "scenarios": ["s"],
                    "checks": [
                        {"label": "x", "scenario": "s", "metric": "m", "op": "<", "bound": 1}
                    ],
                }
            },
            "op must be",
        ),
    ],
)
def test_a_malformed_milestones_file_says_what_and_where(doc, says):
    with pytest.raises(MilestoneError) as err:
        parse_milestones(doc, "m.toml")
    assert says in str(err.value) and "m.toml" in str(err.value)
