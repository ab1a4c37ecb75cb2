"""The Python client against the real server: round trip, spec, autoreset, errors, sharding."""

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import pytest
from unigait.client import (
    Client,
    Session,
    SessionConfig,
    ShardedSession,
    UnigaitError,
    open_session,
)

SHORT = "[env]\nepisode_length_s = 0.1\nrandom_initial_episode_step = false\n"

OBS_FIELDS = ["cmd", "phi", "omega", "q", "qdot", "last_action", "mode", "clock", "ratio"]
LABEL_FIELDS = ["base_lin_vel", "foot_contact", "terrain_normal", "foot_height"]


def test_round_trip_and_spec_slices(server):
    with Client(server) as client:
        info = client.server_info()
        assert info.max_envs_per_session >= 8 and info.protocol_version
        with client.create_session(SessionConfig(num_envs=8, seed=5)) as s:
            spec = s.spec
            assert spec.num_envs == 8 and spec.obs_dim == 53
            assert spec.label_dim == 14 and spec.privileged_dim == 10
            assert spec.obs.field_names == OBS_FIELDS
            assert spec.labels.field_names == LABEL_FIELDS
            assert spec.obs.slice("clock") == slice(47, 51)
            assert len(spec.reward_terms) == 28 and spec.reward_terms[-1] == "biped_feet_air_time"
            assert spec.num_actions == 12 and spec.max_episode_steps == 900
            assert spec.policy_dt == pytest.approx(0.02)
            assert s.initial.obs.shape == (8, 53)
            # A unary step first: once the session has a step stream, steps go there.
            assert s.step_unary(np.zeros((8, 12), np.float32)).step_count == 1
            rng = np.random.default_rng(0)
            for _ in range(3):
                r = s.step(rng.uniform(-1, 1, (8, 12)).astype(np.float32))
                assert r.obs.shape == (8, 53) and r.labels.shape == (8, 14)
                assert r.privileged.shape == (8, 10) and r.reward.shape == (8,)
                assert r.reward_terms is not None and r.reward_terms.shape == (8, 28)
                assert np.isfinite(r.obs).all()
            # The observed one-hot mode agrees with the mode tensor (1 biped, 2 quad).
            one_hot = r.obs[:, spec.obs.slice("mode")]
            np.testing.assert_array_equal(np.argmax(one_hot, axis=1) + 1, r.mode)
            assert np.abs(r.obs[:, spec.obs.slice("clock")]).max() <= 1.0 + 1e-6
            assert r.step_count == 4
            mask = np.zeros(8, bool)
            mask[2] = True
            assert s.reset(mask).obs.shape == (8, 53)


def test_same_seed_same_actions_same_results(server):
    cfg = SessionConfig(num_envs=4, seed=11)
    actions = np.random.default_rng(1).uniform(-1, 1, (5, 4, 12)).astype(np.float32)
    runs = []
    for _ in range(2):
        with open_session(server, cfg) as s:
            runs.append(np.stack([s.step(a).obs for a in actions]))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_same_step_autoreset_carries_final_rows(server):
    cfg = SessionConfig(num_envs=6, seed=2, task_overrides_toml=SHORT)
    with open_session(server, cfg) as s:
        assert s.spec.max_episode_steps == 5
        seen = 0
        for _ in range(5):
            r = s.step(np.zeros((6, 12), np.float32))
            k = len(r.final_env_ids)
            assert r.final_obs.shape == (k, 53) and r.final_labels.shape == (k, 14)
            assert r.final_privileged.shape == (k, 10) and r.final_episode_length.shape == (k,)
            np.testing.assert_array_equal(np.sort(r.final_env_ids), np.flatnonzero(r.dones))
            seen += k
        # Every env has ended by step 5; the time-outs say so at exactly 5 steps.
        timed_out = r.truncated & ~r.terminated
        assert seen >= 6 and timed_out.any()
        rows = np.isin(r.final_env_ids, np.flatnonzero(timed_out))
        assert (r.final_episode_length[rows] == 5).all()
        # The new episode's first observation is not the old episode's last one.
        assert not np.array_equal(r.obs[r.final_env_ids], r.final_obs)


def test_errors_map_to_status_codes(server):
    with Client(server) as client:
        s = client.create_session(SessionConfig(num_envs=4))
        with pytest.raises(UnigaitError) as err:
            s.step_unary(np.zeros((4, 11), np.float32))
        assert err.value.code_name == "INVALID_ARGUMENT" and err.value.details
        with pytest.raises(UnigaitError) as err:
            s.step(np.zeros((3, 12), np.float32))
        assert err.value.code_name == "INVALID_ARGUMENT"
        with pytest.raises(UnigaitError) as err:
            s.step_unary(np.full((4, 12), np.nan, np.float32))
        assert err.value.code_name == "INVALID_ARGUMENT"
        ghost = Session(client, "no-such-session", s.spec, s.initial)
        with pytest.raises(UnigaitError) as err:
            ghost.step_unary(np.zeros((4, 12), np.float32))
        assert err.value.code_name == "NOT_FOUND"
        with pytest.raises(UnigaitError) as err:
            ghost.reset()
        assert err.value.code_name == "NOT_FOUND"
        with pytest.raises(UnigaitError) as err:
            client.create_session(SessionConfig(num_envs=100_000))
        assert err.value.code_name in ("RESOURCE_EXHAUSTED", "INVALID_ARGUMENT")
        # The bad requests left the session usable.
        assert s.step_unary(np.zeros((4, 12), np.float32)).obs.shape == (4, 53)
        s.close()


def test_upright_threshold_is_reported_and_follows_the_curriculum(server):
    # A window of one biped env-step and a promote share of 0: every step promotes by 0.1.
    curriculum = (
        "[modes]\nbiped_probability = 1.0\n"
        "[rewards.upright_curriculum]\nenabled = true\nstart = 0.9\nstep = 0.1\n"
        "promote_share = 0.0\nwindow_steps = 1\n"
    )
    zeros = np.zeros((2, 12), np.float32)
    with open_session(server, SessionConfig(num_envs=2, task_overrides_toml=curriculum)) as s:
        assert s.initial.upright_pitch == pytest.approx(0.9)
        got = [s.step(zeros).upright_pitch for _ in range(7)]
    assert got == pytest.approx([1.0, 1.1, 1.2, 1.3, 1.4, 1.4, 1.4])
    with open_session(server, SessionConfig(num_envs=2)) as s:
        assert s.initial.upright_pitch == pytest.approx(1.4)
        assert s.step(zeros).upright_pitch == pytest.approx(1.4)
    # A start above the paper's threshold is refused as the client's error.
    bad = "[rewards.upright_curriculum]\nenabled = true\nstart = 1.5\n"
    with Client(server) as client, pytest.raises(UnigaitError) as err:
        client.create_session(SessionConfig(num_envs=2, task_overrides_toml=bad))
    assert err.value.code_name == "INVALID_ARGUMENT"
    assert "upright_curriculum.start" in err.value.details


def recorded_names(rrd: bytes, tmp_path: Path) -> tuple[str, set[str]]:
    """A recording's name and its blueprint's view names, read back with rerun's own reader.

    The `.rrd` messages are compressed, so a name shows in the raw bytes only when the
    compressor found nothing earlier to refer it to: a byte search passes or fails with how
    the recording's chunks were batched.
    """
    reader_module = pytest.importorskip("rerun.experimental")
    path = tmp_path / "recording.rrd"
    path.write_bytes(rrd)
    reader = reader_module.RrdReader(path)
    (recording,) = reader.recordings()
    (blueprint,) = reader.blueprints()

    def strings(store: object, column: str) -> list[str]:
        out: list[str] = []
        for chunk in reader.stream(store=store):
            batch = chunk.to_record_batch()
            if column in batch.schema.names:
                out += [s for row in batch[column].to_pylist() if row for s in row]
        return out

    (name,) = strings(recording, "RecordingInfo:name")
    return name, set(strings(blueprint, "ViewBlueprint:display_name"))


def test_a_recording_follows_the_env_asked_for(server, tmp_path):
    policy = (Path(__file__).parent / "data" / "test_policy.onnx").read_bytes()
    with Client(server) as client:

        def views(**kw: int) -> set[str]:
            args = {"num_envs": 3, "seed": 0, "record": True}
            result = client.evaluate(policy, "transition_quad_to_biped", **args, **kw)
            return recorded_names(result.recording_rrd, tmp_path)[1]

        # The layout's followed tab is named after the env.
        followed = views(record_env=2)
        assert "3D: env 2 (followed)" in followed and "3D: env 0 (followed)" not in followed
        assert "3D: env 0 (followed)" in views()
        with pytest.raises(UnigaitError) as err:
            views(record_env=3)
        assert err.value.code_name == "INVALID_ARGUMENT" and "record_env" in err.value.details
        # The refused request harmed nobody: the server still evaluates.
        assert client.evaluate(policy, "transition_quad_to_biped", num_envs=1, seed=0).metrics


def test_a_traversal_records_the_trial_asked_for_in_its_own_case(server, tmp_path):
    # Trials are numbered as the report lists them: 2 forward, then 2 backward; trial 3 is the
    # backward case's second env, and the recording holds that case alone.
    policy = (Path(__file__).parent / "data" / "test_policy.onnx").read_bytes()
    with Client(server) as client:
        result = client.evaluate(
            policy, "stairs_up_quad", num_envs=4, seed=0, record=True, record_env=3
        )
        cases = [o["case"] for o in json.loads(result.report_json)["traversal"]["outcomes"]]
        assert cases == ["forward", "forward", "backward", "backward"]
        name, views = recorded_names(result.recording_rrd, tmp_path)
        assert name == f"stairs_up_quad (unified), {cases[3]}"
        assert "3D: env 1 (followed)" in views and "3D: env 0 (followed)" not in views
        with pytest.raises(UnigaitError) as err:
            client.evaluate(policy, "stairs_up_quad", num_envs=4, seed=0, record=True, record_env=4)
        assert err.value.code_name == "INVALID_ARGUMENT" and "record_env" in err.value.details
        # Table VI's trials are counted as its columns run: 4 in each of 6, so 24 is beyond.
        with pytest.raises(UnigaitError) as err:
            client.evaluate(policy, "table_vi", num_envs=4, seed=0, record=True, record_env=24)
        assert err.value.code_name == "INVALID_ARGUMENT"
        assert "record_env 24 is not among the 24 trials" in err.value.details


def test_a_paused_client_steps_on_after_the_stream_idle_timeout(start_server):
    # A learner paused (a debugger, SIGSTOP, a laptop lid) longer than the stream idle timeout
    # finds its stream ended by the server; the next step opens a new one on the same session.
    address = start_server("--stream-idle-timeout", "1")
    with open_session(address, SessionConfig(num_envs=2, seed=3)) as session:
        actions = np.zeros((2, 12), np.float32)
        first = session.step(actions)
        time.sleep(3.0)
        second = session.step(actions)
        assert second.step_count == first.step_count + 1  # the same session, one step later


def test_sharding_across_two_servers(server, start_server):
    second = start_server()
    cfg = SessionConfig(num_envs=6, seed=20)
    actions = np.random.default_rng(2).uniform(-1, 1, (4, 6, 12)).astype(np.float32)
    with open_session([server, second], cfg) as sharded:
        assert isinstance(sharded, ShardedSession) and sharded.counts == [3, 3]
        got = [sharded.initial.obs] + [sharded.step(a).obs for a in actions]
    # The same batch as two plain sessions seeded seed and seed + 1 on one server.
    expected = []
    with (
        open_session(server, SessionConfig(num_envs=3, seed=20)) as a,
        open_session(server, SessionConfig(num_envs=3, seed=21)) as b,
    ):
        expected.append(np.concatenate([a.initial.obs, b.initial.obs]))
        for act in actions:
            expected.append(np.concatenate([a.step(act[:3]).obs, b.step(act[3:]).obs]))
    np.testing.assert_array_equal(np.stack(got), np.stack(expected))


def test_local_server_ends_with_the_process_that_started_it(server_bin, tmp_path):
    # A learner killed without cleaning up (SIGKILL here) must not leave its server behind.
    import os
    import signal
    import subprocess
    import sys
    import time

    script = (
        "import sys, time\n"
        "from unigait.server_process import LocalServer\n"
        "s = LocalServer(sys.argv[1]); s.start()\n"
        "print(s._proc.pid, flush=True)\n"
        "time.sleep(60)\n"
    )
    parent = subprocess.Popen(
        [sys.executable, "-c", script, str(server_bin)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert parent.stdout is not None
        server_pid = int(parent.stdout.readline())
        os.kill(server_pid, 0)  # running
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            try:
                os.kill(server_pid, 0)
            except ProcessLookupError:
                break
            # A zombie (exited, not yet reaped by init) counts as gone.
            with open(f"/proc/{server_pid}/stat") as f:
                if f.read().split(") ", 1)[1].startswith("Z"):
                    break
            time.sleep(0.1)
        else:
            os.kill(server_pid, signal.SIGKILL)
            raise AssertionError("the server outlived the process that started it")
    finally:
        parent.kill()


def test_every_recipe_stage_task_is_a_valid_task_config(server):
    """A recipe's task table is only checked by the server: every stage of every recipe that
    runs at this commit must open a session, and its weights must reach the effective config."""
    import tomllib

    from unigait.config import session_config
    from unigait.recipes import load_recipe, recipe_names

    checked = 0
    with Client(server) as client:
        for name in recipe_names():
            recipe = load_recipe(name)
            for stage in recipe.stages:
                if not stage.runs_at_head:
                    continue
                cfg = dataclasses.replace(session_config(stage.config), num_envs=1)
                with client.create_session(cfg) as s:
                    effective = tomllib.loads(s.spec.task_config_toml)["rewards"]["weights"]
                asked = stage.config.env.task.get("rewards", {}).get("weights", {})
                for term, weight in asked.items():
                    assert effective[term] == weight, (name, stage.name, term)
                checked += 1
    assert checked >= 6
