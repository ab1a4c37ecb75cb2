"""`unigait checks`: a recipe run's validation.jsonl rows as one table per milestone."""

import json
from pathlib import Path

from unigait.cli import main

FLAT = {
    "tracking_quad": {
        "tracking/quad/lin_vel_error_mps": 0.1,
        "tracking/quad/ang_vel_error_radps": 0.226,
        "tracking/quad/termination_rate": 0.0,
    },
    "tracking_biped": {
        "tracking/biped/upright_share": 1.0,
        "tracking/biped/lin_vel_error_mps": 0.083,
    },
    "transition_biped_to_quad": {"success_rate": 1.0},
    "transition_quad_to_biped": {"success_rate": 0.95},
}
TABLE_VI = {
    "stairs_up_quad/success_rate": 0.7,
    "stairs_down_quad/success_rate": 1.0,
    "slope_quad/success_rate": 0.95,
    "slope_biped/success_rate": 0.8,
    "stairs_up_biped/success_rate": 0.6,
    # stairs_down_biped missing: shown as "-" and not passed.
}


def _stage(run: Path, name: str, *records: dict) -> Path:
    stage = run / name
    stage.mkdir(parents=True)
    (stage / "validation.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    return stage


def _record(iteration: int, milestone: str, evals: dict) -> dict:
    return {"iteration": iteration, "milestone": milestone, "seed": 2000, "evals": evals}


def test_a_run_prints_a_table_per_milestone_with_passing_figures_in_bold(tmp_path, capsys):
    _stage(tmp_path, "01_flat", _record(100, "M2", FLAT))
    _stage(tmp_path, "02_terrain", _record(600, "M3", {**FLAT, "table_vi": TABLE_VI}))
    (tmp_path / "03_no_checks").mkdir()  # a stage that stops on iterations alone
    assert main(["checks", str(tmp_path)]) == 0
    out = capsys.readouterr().out.splitlines()
    m2 = out.index(
        "M2: one policy on flat ground: M1, the biped upright and tracking, both switches"
    )
    assert out[m2 + 2].startswith("| iteration | stage | seed | met | quad lin. vel. error | ")
    # The yaw-rate error (0.226 > 0.2) is the one M2 check not met: not bold, 6 of 7.
    assert out[m2 + 4] == (
        "| 100 | 01_flat | 2000 | 6 of 7 | **0.1** | 0.226 | **0** | **1** | **0.083** | **1** "
        "| **0.95** |"
    )
    m3 = out.index("M3: M2, and the paper's Table VI on at least 4 of its 6 columns")
    assert out[m3 + 2].endswith("| 12 cm stairs up (b) | 15 cm stairs down (b) |")
    # Table VI: 2 of 6 columns at the paper's figures, so its group fails: 6 of 8.
    assert out[m3 + 4] == (
        "| 600 | 02_terrain | 2000 | 6 of 8 | **0.1** | 0.226 | **0** | **1** | **0.083** | **1** "
        "| **0.95** | 0.7 | **1** | 0.95 | 0.8 | **0.6** | - |"
    )


def test_a_stage_folder_prints_its_own_checks_alone(tmp_path, capsys):
    _stage(tmp_path, "01_flat", _record(100, "M2", FLAT))
    stage = _stage(tmp_path, "02_flat", _record(200, "M2", FLAT), _record(300, "M2", FLAT))
    assert main(["checks", str(stage)]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ")]
    assert [r.split(" | ")[:2] for r in rows[2:]] == [["| 200", "02_flat"], ["| 300", "02_flat"]]


def test_a_folder_without_checks_or_with_a_bad_line_is_an_error_naming_it(tmp_path, capsys):
    assert main(["checks", str(tmp_path)]) == 2
    assert f"{tmp_path}: no validation.jsonl here" in capsys.readouterr().err
    stage = _stage(tmp_path, "01_flat", _record(100, "M2", FLAT))
    with (stage / "validation.jsonl").open("a") as f:
        f.write('{"iteration": 200}\n')
    assert main(["checks", str(tmp_path)]) == 2
    assert "validation.jsonl:2: not a check record" in capsys.readouterr().err
    (stage / "validation.jsonl").write_text(json.dumps(_record(100, "M9", FLAT)) + "\n")
    assert main(["checks", str(tmp_path)]) == 2
    assert "01_flat: unknown milestone 'M9'" in capsys.readouterr().err
