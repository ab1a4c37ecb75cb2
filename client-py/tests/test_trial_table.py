"""``python -m unigait trials``: a traversal report's trials, one Markdown table per scenario."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from unigait.cli import main
from unigait.trial_table import TrialTableError, friction_tables, read_trials, trial_tables


def _trial(case: str, env: int, end: str, progress: float, **more: float) -> dict[str, Any]:
    return {
        "env": env,
        "case": case,
        "end": end,
        "progress_m": progress,
        "time_s": 16.0 if end == "timed_out" else 7.5,
        "contact_friction": 0.8,
        **more,
    }


def _traversal(scenario: str, outcomes: list[dict[str, Any]]) -> dict[str, Any]:
    return {"scenario": scenario, "traversal": {"outcomes": outcomes}, "metrics": {}}


@pytest.fixture
def table_vi(tmp_path: Path) -> Path:
    """A two-column Table VI report: a rim walker among the quad's stairs, all slopes crossed."""
    stairs = [
        _trial("forward", 0, "crossed", 4.51, lateral_m=0.1, heading_off_rad=0.05),
        _trial("forward", 1, "timed_out", 4.07, lateral_m=3.91, heading_off_rad=math.pi / 3),
        _trial("backward", 0, "timed_out", 1.65, lateral_m=-0.2, heading_off_rad=-0.1),
        _trial("backward", 1, "terminated", 2.2, lateral_m=0.0, heading_off_rad=0.0),
    ]
    slope = [_trial("up_forward", 0, "crossed", 4.5), _trial("down_forward", 0, "crossed", 4.5)]
    report = {
        "scenario": "table_vi",
        "parts": [_traversal("stairs_up_quad", stairs), _traversal("slope_quad", slope)],
    }
    path = tmp_path / "table_vi.json"
    path.write_text(json.dumps(report))
    return path


def test_the_failed_trials_are_listed_by_the_number_record_env_takes(table_vi: Path) -> None:
    text = trial_tables(read_trials(table_vi))
    assert text == (
        "### stairs_up_quad: 1 of 4 crossed\n\n"
        "| trial | case | end | progress (m) | across (m) | heading off (deg) | time (s) "
        "| friction |\n"
        "| --- | --- | --- | --- | --- | --- | --- | --- |\n"
        "| 1 | forward | timed_out | 4.07 | 3.91 | 60 | 16.00 | 0.80 |\n"
        "| 2 | backward | timed_out | 1.65 | -0.20 | -6 | 16.00 | 0.80 |\n"
        "| 3 | backward | terminated | 2.20 | 0.00 | 0 | 7.50 | 0.80 |\n"
        "\n"
        "### slope_quad: 2 of 2 crossed\n\n"
        "every trial crossed\n\n"
    )


def test_all_lists_every_trial_and_old_reports_show_missing_fields(table_vi: Path) -> None:
    text = trial_tables(read_trials(table_vi), everything=True)
    rows = [line for line in text.splitlines() if line.startswith("| ") and "---" not in line]
    # Two headers, four stairs trials, two slope trials.
    assert len(rows) == 8
    assert "| 0 | forward | crossed | 4.51 | 0.10 | 3 | 7.50 | 0.80 |" in rows
    # The slope trials were written without the pose at the end: shown as "-". They are
    # numbered on from the stairs', as a table_vi evaluation's --record-env counts them.
    assert "| 5 | down_forward | crossed | 4.50 | - | - | 7.50 | 0.80 |" in rows


def test_a_single_scenario_report_is_one_table(tmp_path: Path) -> None:
    path = tmp_path / "one.json"
    report = _traversal("stairs_up_biped", [_trial("forward", 0, "timed_out", 3.4)])
    path.write_text(json.dumps(report))
    trials = read_trials(path)
    assert [(t.scenario, t.number, t.outcome["end"]) for t in trials] == [
        ("stairs_up_biped", 0, "timed_out")
    ]


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("not json", "one.json"),
        ('{"scenario": "tracking_quad", "traversal": null}', "no traversal trials"),
        ("[1, 2]", "not an evaluation report"),
    ],
)
def test_reports_without_trials_are_errors_naming_the_file(
    tmp_path: Path, content: str, message: str
) -> None:
    path = tmp_path / "one.json"
    path.write_text(content)
    with pytest.raises(TrialTableError, match=message):
        read_trials(path)


def test_the_command_prints_the_tables_and_exits_2_on_a_bad_report(
    table_vi: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["trials", str(table_vi)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("### stairs_up_quad: 1 of 4 crossed")
    assert main(["trials", str(tmp_path / "missing.json")]) == 2
    assert "missing.json" in capsys.readouterr().err


def test_by_friction_counts_each_cases_crossings_in_friction_bins(tmp_path: Path) -> None:
    slope = [
        _trial("up_forward", 0, "timed_out", 1.8, contact_friction=0.61),
        _trial("up_forward", 1, "crossed", 4.5, contact_friction=0.64),
        _trial("up_forward", 2, "timed_out", 2.0, contact_friction=0.75),
        _trial("up_forward", 3, "crossed", 4.5, contact_friction=1.0),  # an edge opens its bin
        _trial("up_forward", 4, "crossed", 4.5, contact_friction=1.27),
        _trial("up_backward", 0, "crossed", 4.5, contact_friction=0.66),
    ]
    stairs = [_trial("forward", 0, "crossed", 4.5)]
    path = tmp_path / "r.json"
    report = {"parts": [_traversal("slope_biped", slope), _traversal("stairs_up_quad", stairs)]}
    path.write_text(json.dumps(report))
    assert friction_tables(read_trials(path)) == (
        "### slope_biped: crossed / trials by contact friction\n\n"
        "| case | < 0.65 | 0.65-0.70 | 0.70-0.80 | 0.80-0.90 | 0.90-1.00 | >= 1.00 |\n"
        "| --- | --- | --- | --- | --- | --- | --- |\n"
        "| up_forward | 1/2 | - | 0/1 | - | - | 2/2 |\n"
        "| up_backward | - | 1/1 | - | - | - | - |\n"
        "\n"
        "### stairs_up_quad: crossed / trials by contact friction\n\n"
        "| case | < 0.65 | 0.65-0.70 | 0.70-0.80 | 0.80-0.90 | 0.90-1.00 | >= 1.00 |\n"
        "| --- | --- | --- | --- | --- | --- | --- |\n"
        "| forward | - | - | - | 1/1 | - | - |\n"
        "\n"
    )
    assert main(["trials", "--by-friction", str(path)]) == 0
