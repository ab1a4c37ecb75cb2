//! The protocol's contract as checks any server must pass, in the spirit of dm_env_rpc's
//! compliance tests. Run with `unigait-client check --server ADDR` or from the test suite.

use std::future::Future;

use tonic::Code;

use crate::client::{Client, Session, Step};
use crate::error::ClientError;
use crate::v1;

/// Outcome of one check.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CheckOutcome {
    /// Check name.
    pub name: &'static str,
    /// Whether it passed.
    pub passed: bool,
    /// What went wrong (empty when passed).
    pub detail: String,
}

type CheckResult = Result<(), String>;

fn ensure(condition: bool, message: impl FnOnce() -> String) -> CheckResult {
    if condition { Ok(()) } else { Err(message()) }
}

fn err(e: ClientError) -> String {
    e.to_string()
}

fn config(num_envs: u32, seed: u64, overrides: &str) -> v1::SessionConfig {
    v1::SessionConfig {
        num_envs,
        seed,
        task_overrides_toml: overrides.into(),
        terrain: None,
        autoreset: v1::AutoresetMode::SameStep as i32,
        reward_terms: true,
        robot_drawing: false,
    }
}

/// Zero actions for a session.
fn zeros(session: &Session) -> Vec<f32> {
    vec![0.0; session.spec.num_envs() * 12]
}

fn expect_code(result: Result<impl Sized, ClientError>, code: Code, what: &str) -> CheckResult {
    match result {
        Ok(_) => Err(format!("{what}: accepted, expected {code:?}")),
        Err(e) if e.code() == Some(code) => Ok(()),
        Err(e) => Err(format!("{what}: got `{e}`, expected {code:?}")),
    }
}

async fn create_and_close(client: &Client) -> CheckResult {
    let mut c = client.clone();
    let session = c.create_session(config(4, 1, "")).await.map_err(err)?;
    let id = session.id.clone();
    session.close().await.map_err(err)?;
    let mut gone = c.create_session(config(1, 1, "")).await.map_err(err)?;
    gone.id = id;
    expect_code(
        gone.step(&[0.0; 12]).await,
        Code::NotFound,
        "step on a closed session",
    )
}

async fn spec_matches_tensors(client: &Client) -> CheckResult {
    let mut c = client.clone();
    let mut session = c.create_session(config(5, 2, "")).await.map_err(err)?;
    let n = 5;
    let step = session.step(&zeros(&session)).await.map_err(err)?;
    for (name, values) in [
        ("obs", step.obs().map_err(err)?.len()),
        ("labels", step.labels().map_err(err)?.len()),
        ("privileged", step.privileged().map_err(err)?.len()),
        ("reward", step.reward().map_err(err)?.len()),
        ("reward_terms", step.reward_terms().map_err(err)?.len()),
    ] {
        let row = session
            .spec
            .row_size(name)
            .ok_or(format!("spec lacks `{name}`"))?;
        ensure(values == n * row, || {
            format!("`{name}` holds {values} values, spec says {n} x {row}")
        })?;
        let fields: usize = session
            .spec
            .tensor(name)
            .map(|t| t.fields.iter().map(|f| f.size as usize).sum())
            .unwrap_or(0);
        ensure(fields == 0 || fields == row, || {
            format!("`{name}`'s fields cover {fields} of {row} values")
        })?;
    }
    ensure(
        session.spec.0.reward_terms.len() == session.spec.row_size("reward_terms").unwrap_or(0),
        || "reward term names do not match reward_terms' row".into(),
    )?;
    ensure(session.spec.0.joint_names.len() == 12, || {
        "the spec must name 12 joints".into()
    })?;
    session.close().await.map_err(err)
}

fn ended(step: &Step) -> Result<Vec<usize>, String> {
    let t = step.terminated().map_err(err)?;
    let u = step.truncated().map_err(err)?;
    Ok((0..t.len()).filter(|&i| t[i] != 0 || u[i] != 0).collect())
}

async fn autoreset_and_truncation(client: &Client) -> CheckResult {
    let mut c = client.clone();
    // A 5-step episode on calm robots: every env times out at step 5.
    let overrides = "[env]\nepisode_length_s = 0.1\nrandom_initial_episode_step = false\n[init]\npitch = [0.0, 0.0]\n";
    let mut session = c
        .create_session(config(6, 3, overrides))
        .await
        .map_err(err)?;
    let mut stream = session.stream().await.map_err(err)?;
    let actions = zeros(&session);
    for k in 1..=5 {
        let step = stream.step(&actions).await.map_err(err)?;
        let done = ended(&step)?;
        if k < 5 {
            ensure(done.is_empty(), || {
                format!("envs {done:?} ended at step {k} of a 5-step episode")
            })?;
            continue;
        }
        let truncated = step.truncated().map_err(err)?;
        let terminated = step.terminated().map_err(err)?;
        ensure(truncated.iter().all(|&t| t == 1), || {
            format!("time-out not reported as truncation: {truncated:?}")
        })?;
        ensure(terminated.iter().all(|&t| t == 0), || {
            "a time-out was reported as termination".into()
        })?;
        let ids = step.final_env_ids().map_err(err)?;
        ensure(ids.as_ref() == [0, 1, 2, 3, 4, 5], || {
            format!("final_env_ids {ids:?}")
        })?;
        let final_obs = step.final_obs().map_err(err)?;
        let obs = step.obs().map_err(err)?;
        ensure(final_obs.len() == obs.len(), || {
            "final_obs must hold one row per ended env".into()
        })?;
        ensure(final_obs.as_ref() != obs.as_ref(), || {
            "obs must be the new episode's first observation".into()
        })?;
    }
    drop(stream);
    session.close().await.map_err(err)
}

async fn termination(client: &Client) -> CheckResult {
    let mut c = client.clone();
    // Robots dropped nose-first with limp actions: the head hits the ground.
    let overrides = "[env]\nrandom_initial_episode_step = false\n[init]\npitch = [1.5, 1.5]\n";
    let mut session = c
        .create_session(config(8, 4, overrides))
        .await
        .map_err(err)?;
    let actions = zeros(&session);
    let mut seen = false;
    for _ in 0..100 {
        let step = session.step(&actions).await.map_err(err)?;
        let t = step.terminated().map_err(err)?;
        let u = step.truncated().map_err(err)?;
        ensure(
            t.iter().zip(u.iter()).all(|(a, b)| !(*a == 1 && *b == 1)),
            || "an env was both terminated and truncated".into(),
        )?;
        seen |= t.contains(&1);
        if seen {
            break;
        }
    }
    ensure(seen, || {
        "no termination in 100 steps of robots falling on their heads".into()
    })?;
    session.close().await.map_err(err)
}

async fn determinism(client: &Client) -> CheckResult {
    let mut trace = Vec::new();
    for _ in 0..2 {
        let mut c = client.clone();
        let mut session = c.create_session(config(6, 42, "")).await.map_err(err)?;
        let mut bytes = session
            .initial
            .0
            .obs
            .clone()
            .map(|t| t.data.to_vec())
            .unwrap_or_default();
        for k in 0..15 {
            let actions: Vec<f32> = (0..6 * 12)
                .map(|i| ((i * 7 + k * 13) % 17) as f32 / 8.0 - 1.0)
                .collect();
            let step = session.step(&actions).await.map_err(err)?;
            for t in [&step.0.obs, &step.0.reward, &step.0.labels]
                .into_iter()
                .flatten()
            {
                bytes.extend_from_slice(&t.data);
            }
        }
        session.close().await.map_err(err)?;
        trace.push(bytes);
    }
    ensure(trace[0] == trace[1], || {
        "same config, seed and actions gave different bytes".into()
    })
}

async fn bad_inputs(client: &Client) -> CheckResult {
    let mut c = client.clone();
    let mut session = c.create_session(config(2, 5, "")).await.map_err(err)?;
    expect_code(
        session.step(&[0.0; 12]).await,
        Code::InvalidArgument,
        "actions for 1 env sent to 2",
    )?;
    let mut nan = zeros(&session);
    nan[3] = f32::NAN;
    expect_code(
        session.step(&nan).await,
        Code::InvalidArgument,
        "NaN in actions",
    )?;
    let mut inf = zeros(&session);
    inf[20] = f32::INFINITY;
    expect_code(
        session.step(&inf).await,
        Code::InvalidArgument,
        "inf in actions",
    )?;
    expect_code(
        c.create_session(config(0, 1, "")).await,
        Code::InvalidArgument,
        "zero envs",
    )?;
    expect_code(
        c.create_session(config(1, 1, "[rewards]\nupright_pitch = 9.0\n"))
            .await,
        Code::InvalidArgument,
        "an out-of-range config value",
    )?;
    expect_code(
        c.create_session(config(1, 1, "[rewards\n")).await,
        Code::InvalidArgument,
        "malformed TOML",
    )?;
    let info = c.server_info().await.map_err(err)?;
    expect_code(
        c.create_session(config(info.max_envs_per_session + 1, 1, ""))
            .await,
        Code::ResourceExhausted,
        "more envs than the server allows",
    )?;
    let mut ghost = c.create_session(config(1, 1, "")).await.map_err(err)?;
    let real = ghost.id.clone();
    ghost.id = "no-such-session".into();
    expect_code(
        ghost.step(&[0.0; 12]).await,
        Code::NotFound,
        "unknown session",
    )?;
    ghost.id = real;
    ghost.close().await.map_err(err)?;
    // A second stream on the same session is refused; the first keeps working.
    let mut first = session.stream().await.map_err(err)?;
    first.step(&zeros(&session)).await.map_err(err)?;
    let mut second = session.stream().await.map_err(err)?;
    expect_code(
        second.step(&zeros(&session)).await,
        Code::FailedPrecondition,
        "a second step stream",
    )?;
    first.step(&zeros(&session)).await.map_err(err)?;
    drop(first);
    session.close().await.map_err(err)
}

async fn isolation(client: &Client) -> CheckResult {
    // A session stepped with bad requests in between gives the same results as an untouched one.
    let mut c = client.clone();
    let mut a = c.create_session(config(3, 9, "")).await.map_err(err)?;
    let mut b = c.create_session(config(3, 9, "")).await.map_err(err)?;
    for _ in 0..5 {
        let ra = a.step(&zeros(&a)).await.map_err(err)?;
        let _ = b.step(&[f32::NAN; 36]).await;
        let _ = b.step(&[0.0; 5]).await;
        let rb = b.step(&zeros(&b)).await.map_err(err)?;
        ensure(ra.0.obs == rb.0.obs, || {
            "bad requests changed a session's results".into()
        })?;
    }
    a.close().await.map_err(err)?;
    b.close().await.map_err(err)
}

async fn run_check<F: Future<Output = CheckResult>>(name: &'static str, check: F) -> CheckOutcome {
    match check.await {
        Ok(()) => CheckOutcome {
            name,
            passed: true,
            detail: String::new(),
        },
        Err(detail) => CheckOutcome {
            name,
            passed: false,
            detail,
        },
    }
}

/// Run every check against the server `client` talks to.
pub async fn run_all(client: &Client) -> Vec<CheckOutcome> {
    vec![
        run_check("create_and_close", create_and_close(client)).await,
        run_check("spec_matches_tensors", spec_matches_tensors(client)).await,
        run_check("autoreset_and_truncation", autoreset_and_truncation(client)).await,
        run_check("termination", termination(client)).await,
        run_check("determinism", determinism(client)).await,
        run_check("bad_inputs", bad_inputs(client)).await,
        run_check("isolation", isolation(client)).await,
    ]
}
