"""Checkpoint averaging: the mean of the networks' weights, its refusals, the CLI and ship."""

import pytest
import torch
from test_cli import SMALL

from unigait.averaging import AveragingError, average_checkpoints, describe_average
from unigait.checkpoints import export_policy
from unigait.cli import main


def _checkpoint(path, iteration, actor, estimator, steps=7):
    torch.save(
        {
            "iteration": iteration,
            "actor_critic": {"w": torch.tensor(actor), "count": torch.tensor(steps)},
            "estimator": {"w": torch.tensor(estimator)},
            "learning_rate": 1e-4 * iteration,
        },
        path,
    )
    return path


def test_the_networks_are_averaged_and_the_rest_is_the_last_checkpoints(tmp_path):
    a = _checkpoint(tmp_path / "model_10.pt", 10, [1.0, 2.0], [0.0, -4.0])
    b = _checkpoint(tmp_path / "model_20.pt", 20, [3.0, 6.0], [1.0, 4.0])
    c = _checkpoint(tmp_path / "model_30.pt", 30, [5.0, 1.0], [2.0, 3.0])
    out = average_checkpoints([a, b, c])
    assert out["actor_critic"]["w"].tolist() == [3.0, 3.0]
    assert out["estimator"]["w"].tolist() == [1.0, 1.0]
    assert out["actor_critic"]["count"].item() == 7  # an integer buffer is kept, not averaged
    assert out["iteration"] == 30 and out["learning_rate"] == pytest.approx(3e-3)
    assert out["averaged_from"] == [10, 20, 30]
    assert describe_average([10, 20, 30]) == (
        "The weights are the mean of 3 checkpoints' (iterations 10-30, every 10; decision "
        "record 0044), not one checkpoint's."
    )
    assert "every" not in describe_average([10, 20, 40])


def test_checkpoints_that_are_not_the_same_networks_are_refused(tmp_path):
    a = _checkpoint(tmp_path / "model_1.pt", 1, [1.0, 2.0], [0.0])
    wider = _checkpoint(tmp_path / "model_2.pt", 2, [1.0, 2.0, 3.0], [0.0])
    with pytest.raises(AveragingError, match=r"model_1.pt: actor_critic.w has shape \(2,\)"):
        average_checkpoints([a, wider])
    counted = _checkpoint(tmp_path / "model_3.pt", 3, [1.0, 2.0], [0.0], steps=8)
    with pytest.raises(AveragingError, match="integer tensor"):
        average_checkpoints([a, counted])
    (tmp_path / "model_4.ckpt").write_bytes(b"UGLCKPT1")
    with pytest.raises(AveragingError, match="only the Python learner"):
        average_checkpoints([a, tmp_path / "model_4.ckpt"])
    torch.save({"iteration": 5}, tmp_path / "model_5.pt")
    with pytest.raises(AveragingError, match="not a Python learner's checkpoint"):
        average_checkpoints([a, tmp_path / "model_5.pt"])
    with pytest.raises(AveragingError, match="at least one"):
        average_checkpoints([])


def test_a_runs_last_checkpoints_average_export_and_ship(fake_server, tmp_path, capsys):
    address, _ = fake_server
    run = tmp_path / "run"
    train = ["train", "--server", address, "--num-envs", "6", "--log-dir", str(run), *SMALL]
    assert main([*train, "--iterations", "3"]) == 0
    averaged = tmp_path / "avg.pt"
    assert main(["average", "--run-dir", str(run), "--last", "2", "--out", str(averaged)]) == 0
    two = [torch.load(run / f"model_{i}.pt", weights_only=False) for i in (2, 3)]
    out = torch.load(averaged, weights_only=False)
    for key in ("actor_critic", "estimator"):
        for name, value in out[key].items():
            if value.is_floating_point():
                mean = (two[0][key][name] + two[1][key][name]) / 2
                torch.testing.assert_close(value, mean, msg=f"{key}.{name}")
    assert out["averaged_from"] == [2, 3] and out["iteration"] == 3
    assert not torch.equal(two[0]["estimator"]["net.0.weight"], two[1]["estimator"]["net.0.weight"])
    export_policy(averaged, tmp_path / "avg.onnx")  # checked against onnxruntime
    assert "iterations 2-3, every 1" in capsys.readouterr().out
    # The same from the files named.
    named = [str(run / "model_2.pt"), str(run / "model_3.pt")]
    assert main(["average", *named, "--out", str(tmp_path / "named.pt")]) == 0
    ship = ["ship", "--server", address, "--run-dir", str(run), "--recipe", "unified_flat"]
    ship += ["--name", "u", "--out-root", str(tmp_path / "policies"), "--num-envs", "4"]
    assert main([*ship, "--average-last", "2"]) == 0
    folder = tmp_path / "policies" / "u"
    shipped = torch.load(folder / "model.pt", weights_only=False)
    assert shipped["averaged_from"] == [2, 3]
    card = (folder / "MODEL_CARD.md").read_text()
    assert "The weights are the mean of 2 checkpoints' (iterations 2-3, every 1" in card
    assert "--average-last 2" in card
    # An averaged file shipped as --checkpoint says the same.
    assert main([*ship, "--checkpoint", str(averaged)]) == 0
    assert "mean of 2 checkpoints' (iterations 2-3" in (folder / "MODEL_CARD.md").read_text()
    capsys.readouterr()
    # Refusals: too few checkpoints, a checkpoint given too, nothing to average.
    assert main([*ship, "--average-last", "9"]) == 2
    assert "holds 3 numbered checkpoints" in capsys.readouterr().err
    assert main([*ship, "--average-last", "2", "--checkpoint", str(run / "model_2.pt")]) == 2
    assert main(["average", "--run-dir", str(run), "--out", str(tmp_path / "x.pt")]) == 2
    assert main(["average", str(run / "model_1.ckpt"), "--out", str(tmp_path / "x.pt")]) == 2
    assert "only the Python learner" in capsys.readouterr().err


def test_a_cards_reproduce_lines_average_the_recipe_stages_checkpoints():
    from types import SimpleNamespace

    from unigait.model_card import _average_then_ship

    card = SimpleNamespace(recipe="unified_terrain", ship_command="python -m unigait ship --x")
    provenance = {"recipe": "unified_terrain", "stage": 36, "stage_name": "knee_price"}
    every_25 = {"averaged_from": [35800, 35825, 35850], "provenance": provenance}
    assert _average_then_ship(card, every_25) == [
        "python -m unigait average runs/unified_terrain/36_knee_price/model_{35800..35850..25}.pt"
        " --out runs/unified_terrain/averaged_35800-35850.pt",
        "python -m unigait ship --x --checkpoint runs/unified_terrain/averaged_35800-35850.pt",
    ]
    uneven = {"averaged_from": [10, 30, 40], "provenance": provenance}
    assert _average_then_ship(card, uneven)[0].startswith(
        "python -m unigait average runs/unified_terrain/36_knee_price/model_10.pt "
        "runs/unified_terrain/36_knee_price/model_30.pt"
    )
    # One checkpoint, or no recipe stage to name: the ship line alone.
    assert _average_then_ship(card, {"provenance": provenance}) == [card.ship_command]
    assert _average_then_ship(card, {"averaged_from": [1, 2]}) == [card.ship_command]
