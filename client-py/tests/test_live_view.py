"""The live view of a training run (``train --view``) and its TensorBoard events (fake server).

The recordings are read back with rerun's own reader: what a viewer gets.
"""

import csv
import math
from collections import defaultdict
from pathlib import Path

import pytest
from fakes import REWARD_TERMS
from test_cli import SMALL
from test_recipes import two_stages

from unigait.cli import main, training_command
from unigait.live_view import CURVES, EVENTS, ViewError, parse_view, recording_id
from unigait.milestones import milestone

rr = pytest.importorskip("rerun")
from rerun.experimental import RrdReader  # noqa: E402


def read_rrd(path: Path) -> tuple[str, dict[str, dict[int, float]], list[str], int]:
    """(recording id, scalar entity -> {iteration: value}, events, blueprints) of a file."""
    reader = RrdReader(path)
    (entry,) = reader.recordings()
    series: dict[str, dict[int, float]] = defaultdict(dict)
    events: list[str] = []
    for chunk in reader.stream():
        if chunk.entity_path == f"/{EVENTS}":
            rows = chunk.to_record_batch()["TextLog:text"].to_pylist()
            events += [t for row in rows for t in row]
        if not chunk.entity_path.startswith(f"/{CURVES}/"):
            continue
        batch = chunk.to_record_batch()
        name = chunk.entity_path.removeprefix(f"/{CURVES}/")
        its, values = batch["iteration"].to_pylist(), batch["Scalars:scalars"].to_pylist()
        for it, row in zip(its, values, strict=True):
            series[name][int(it)] = float(row[0])
    return entry.recording_id, dict(series), events, len(reader.blueprints())


def csv_rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def same(csv_value: str, value: float) -> bool:
    if csv_value == "":
        return math.isnan(value)
    return math.isclose(float(csv_value), value, rel_tol=1e-5, abs_tol=1e-12)


def test_a_run_saves_every_scalar_as_curves_and_a_resume_continues_its_recording(
    fake_server, tmp_path, capsys
):
    address, _ = fake_server
    log_dir = tmp_path / "run"
    args = ["train", "--server", address, "--num-envs", "6", "--log-dir", str(log_dir), *SMALL]
    first = tmp_path / "view.rrd"
    assert main([*args, "--iterations", "2", "--view", "save", str(first), "--tensorboard"]) == 0
    rec_id, series, events, blueprints = read_rrd(first)
    rows = csv_rows(log_dir / "progress.csv")
    # Every CSV column is a curve with the CSV's value at each iteration, nothing else.
    assert set(series) == set(rows[0])
    for row in rows:
        it = int(float(row["iteration"]))
        for name, value in row.items():
            assert same(value, series[name][it]), (name, it)
    assert sorted(series["iteration"]) == [1, 2]
    # What the issue lists: reward and each term, length, terrain level per type and mode,
    # upright threshold, learning rate, KL, action noise, throughput and the time split.
    terms = REWARD_TERMS
    for name in [
        "mean_episode_reward",
        "mean_episode_length",
        *(f"episode_reward/{t}" for t in terms),
        "terrain_level/flat",
        "terrain_level/biped",
        "terrain_level/quad",
        "curriculum/upright_pitch",
        "learning_rate",
        "kl",
        "action_std",
        "env_steps_per_s",
        "time_share/simulation",
        "time_share/inference",
        "time_share/update",
    ]:
        assert name in series, name
    assert blueprints == 1 and events == ["run started at iteration 0"]
    assert rec_id == recording_id(log_dir)

    # TensorBoard: the same names, the same values, step = iteration.
    pytest.importorskip("tensorboard")
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    (event_file,) = log_dir.glob("events.out.tfevents.*")
    acc = EventAccumulator(str(event_file))
    acc.Reload()
    assert set(acc.Tags()["scalars"]) == set(rows[0])
    kl = {e.step: e.value for e in acc.Scalars("kl")}
    assert kl.keys() == {1, 2} and all(same(r["kl"], kl[int(r["iteration"])]) for r in rows)

    # A resume writes its part to another file of the same recording, saying where it resumed.
    second = tmp_path / "view_resumed.rrd"
    resume = ["--resume", str(log_dir / "model_2.pt"), "--view", "save", str(second)]
    assert main([*args, "--iterations", "3", *resume]) == 0
    rec_id2, series2, events2, _ = read_rrd(second)
    assert rec_id2 == rec_id and sorted(series2["iteration"]) == [3]
    assert events2 == [f"run resumed from {log_dir / 'model_2.pt'} at iteration 2"]
    # Resumed again into the first path: that file is kept, the new part goes beside it.
    before = first.read_bytes()
    resume = ["--resume", str(log_dir / "model_3.pt"), "--view", "save", str(first)]
    assert main([*args, "--iterations", "4", *resume]) == 0
    assert first.read_bytes() == before
    rec_id3, series3, _, _ = read_rrd(tmp_path / "view.2.rrd")
    assert rec_id3 == rec_id and sorted(series3["iteration"]) == [4]
    # How the run was watched is not part of the recipe a checkpoint keeps.
    assert "--view" not in training_command([*args, "--view", "connect", "URL", "--tensorboard"])
    assert "--tensorboard" not in training_command([*args, "--tensorboard"])
    capsys.readouterr()


def test_a_recipe_view_counts_the_recipes_iterations_across_stages(fake_server, tmp_path):
    address, _ = fake_server
    run = tmp_path / "run"
    view = tmp_path / "recipe.rrd"
    command = ["train", "--server", address, "--recipe", str(two_stages(tmp_path))]
    command += ["--log-dir", str(run), "--view", "save", str(view), "--tensorboard"]
    assert main(command) == 0
    _, series, events, _ = read_rrd(view)
    # Stage 1 trains iterations 1-2, stage 2 (carry = all) 3-5: one curve over 1-5.
    assert sorted(series["iteration"].items()) == [(i, float(i)) for i in range(1, 6)]
    assert events == [
        "stage 1 of 2 (first) starts at its iteration 0",
        "stage 2 of 2 (second) starts at its iteration 2",
    ]
    assert list((run / "02_second").glob("events.out.tfevents.*"))


@pytest.mark.parametrize(
    ("args", "kind", "where"),
    [
        (["serve"], "serve", "127.0.0.1:9876"),
        (["serve", "0"], "serve", "0"),
        (["connect", "rerun+http://h:1/proxy"], "connect", "rerun+http://h:1/proxy"),
        (["save", "a.rrd"], "save", "a.rrd"),
    ],
)
def test_view_arguments(args, kind, where):
    target = parse_view(args)
    assert (target.kind, target.where) == (kind, where)


@pytest.mark.parametrize("args", [[], ["save"], ["connect"], ["serve", "x:y"], ["show", "a"]])
def test_a_malformed_view_is_refused_with_the_forms_it_takes(args, fake_server, tmp_path, capsys):
    with pytest.raises(ViewError):
        parse_view(args)
    address, _ = fake_server
    if args:
        code = main(["train", "--server", address, "--log-dir", str(tmp_path), "--view", *args])
        assert code == 2 and "--view" in capsys.readouterr().err


def test_a_served_view_listens_on_loopback_and_stops_with_the_run(tmp_path):
    from unigait.live_view import LiveView

    view = LiveView(parse_view(["serve", "0"]), tmp_path, "test")
    try:
        assert view.url.startswith("rerun+http://127.0.0.1:") and view.url.endswith("/proxy")
        assert view._server is not None and view._server.proc.poll() is None
        group = view._server.proc.pid
        # The `rerun` launcher and the viewer binary it started.
        assert len(_group_members(group)) >= 2
        view.log({"iteration": 1.0, "kl": 0.01})
    finally:
        view.close()
    assert view._server.proc.poll() is not None
    assert _group_members(group) == []  # the binary did not outlive its launcher


def _group_members(group: int) -> list[int]:
    """Live (not zombie) processes of process group ``group``, from /proc."""
    members = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue  # it ended while we looked
        if int(fields[2]) == group and fields[0] != "Z":
            members.append(int(stat.parent.name))
    return members


def test_every_m_iterations_a_milestone_evaluation_on_a_fixed_seed_goes_to_the_view(
    fake_server, tmp_path
):
    address, servicer = fake_server
    view = tmp_path / "view.rrd"
    args = ["train", "--server", address, "--num-envs", "6", "--log-dir", str(tmp_path / "r")]
    args += [*SMALL, "--iterations", "5", "--view", "save", str(view), "--view-eval-every", "2"]
    assert main(args) == 0
    # M1 is judged on tracking_quad; the recipes' validation seed, 64 envs, at iterations 2, 4.
    assert servicer.evaluated == [("tracking_quad", 2000, 64)] * 2
    _, series, events, _ = read_rrd(view)
    assert series["eval/criteria_met"] == {2: 0.0, 4: 0.0}  # the fake reports no M1 metric
    assert series["eval/tracking_quad/num_envs"] == {2: 64.0, 4: 64.0}
    # The verdict says what is missing, as the run's log does.
    unmet = "; ".join(milestone("M1").unmet({}))
    assert unmet.startswith("quad") and "missing" in unmet
    assert events[1:] == [f"M1: 0/3 criteria met on seed 2000; unmet: {unmet}"] * 2
    assert sorted(series["iteration"]) == [1, 2, 3, 4, 5]

    # A recipe: the view's evaluations at the recipe's iterations 2 and 4, across its stages.
    servicer.evaluated.clear()
    recipe_view = tmp_path / "recipe.rrd"
    command = ["train", "--server", address, "--recipe", str(two_stages(tmp_path))]
    command += ["--log-dir", str(tmp_path / "run"), "--view", "save", str(recipe_view)]
    assert main([*command, "--view-eval-every", "2", "--view-eval-milestone", "M2"]) == 0
    assert [s for s, _, _ in servicer.evaluated] == [
        "tracking_quad", "tracking_biped", "transition_biped_to_quad", "transition_quad_to_biped"
    ] * 2  # fmt: skip
    _, series, _, _ = read_rrd(recipe_view)
    assert sorted(series["eval/criteria_met"]) == [2, 4]


def test_an_unknown_evaluation_milestone_is_refused(fake_server, tmp_path, capsys):
    address, _ = fake_server
    args = ["train", "--server", address, "--log-dir", str(tmp_path), "--view", "save", "x.rrd"]
    assert main([*args, "--view-eval-milestone", "M9"]) == 2
    assert "--view-eval-milestone" in capsys.readouterr().err


def test_panels_take_names_prefixes_one_level_down_and_patterns():
    from unigait.live_view import _matches

    names = [
        "terrain_level",
        "terrain_level/stairs_up",
        "terrain_level/quad",
        "terrain_level/stairs_up/quad",
        "terrain_level/stairs_up/biped",
        "terrain_levels",
    ]
    mean = ("terrain_level", "terrain_level/")
    assert [n for n in names if _matches(n, mean)] == names[:3]
    four_legs = ("terrain_level/*/quad",)
    assert [n for n in names if _matches(n, four_legs)] == ["terrain_level/stairs_up/quad"]
    assert not _matches("terrain_level//quad", four_legs)
