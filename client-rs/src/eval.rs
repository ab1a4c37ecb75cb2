//! Evaluating an ONNX policy on the server: `unigait eval` and `unigait record`.
//!
//! The server rolls the policy out on its own envs over a named scenario (see the server's
//! scenario list: the Table VI columns `stairs_up_quad` ... `stairs_down_biped`, `table_vi`,
//! `transition_biped_to_quad`, `transition_quad_to_biped`, `tracking_quad`, `tracking_biped`,
//! `flat_quad`, `flat_biped`) and answers with metrics, a JSON report and, for `record`, a
//! rerun recording of env 0.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use tonic::Request;
use tonic::metadata::MetadataValue;
use unigait_proto::v1;

use crate::{Client, ClientError};

/// `unigait eval`: evaluate a policy and print its metrics.
#[derive(Clone, Debug, clap::Args)]
pub struct EvalArgs {
    /// The ONNX policy (input [batch, 3, 53], output [batch, 12]); the quad policy of the
    /// two-policy baseline when --biped-policy is given.
    #[arg(long)]
    pub policy: PathBuf,
    /// Scenario name, e.g. stairs_up_quad, table_vi, transition_biped_to_quad.
    #[arg(long)]
    pub scenario: String,
    /// A biped policy: evaluate the two-policy baseline (switched at the mode change).
    #[arg(long)]
    pub biped_policy: Option<PathBuf>,
    /// Envs (trials); 0 = the scenario's default.
    #[arg(long, default_value_t = 0)]
    pub envs: u32,
    /// Seed of the server's envs.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print the full JSON report on stdout (the table goes to stderr).
    #[arg(long)]
    pub json: bool,
}

/// `unigait record`: evaluate a policy and save a rerun recording of env 0.
#[derive(Clone, Debug, clap::Args)]
pub struct RecordArgs {
    /// The ONNX policy.
    #[arg(long)]
    pub policy: PathBuf,
    /// Scenario name.
    #[arg(long)]
    pub scenario: String,
    /// A biped policy for the two-policy baseline.
    #[arg(long)]
    pub biped_policy: Option<PathBuf>,
    /// Envs; 0 = the scenario's default.
    #[arg(long, default_value_t = 0)]
    pub envs: u32,
    /// Seed of the server's envs.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Where to write the recording (open it with `rerun rollout.rrd`).
    #[arg(long)]
    pub out: PathBuf,
}

fn read_policy(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).with_context(|| format!("cannot read policy `{}`", path.display()))
}

/// An Evaluate request from policy files.
pub fn request(
    policy: &Path,
    biped_policy: Option<&Path>,
    scenario: &str,
    envs: u32,
    seed: u64,
    record: bool,
) -> Result<v1::EvaluateRequest> {
    Ok(v1::EvaluateRequest {
        policy_onnx: read_policy(policy)?.into(),
        biped_policy_onnx: match biped_policy {
            Some(p) => read_policy(p)?.into(),
            None => Default::default(),
        },
        scenario: scenario.to_string(),
        num_envs: envs,
        seed,
        record,
    })
}

/// Send an Evaluate request (with `token` as a bearer token when given).
pub async fn evaluate(
    client: &mut Client,
    token: Option<&str>,
    message: v1::EvaluateRequest,
) -> Result<v1::EvaluateResponse, ClientError> {
    let mut r = Request::new(message);
    if let Some(t) = token {
        let value: MetadataValue<_> = format!("Bearer {t}")
            .parse()
            .map_err(|_| ClientError::Address("the token is not valid header text".into()))?;
        r.metadata_mut().insert("authorization", value);
    }
    Ok(client.raw().evaluate(r).await?.into_inner())
}

/// The metrics as an aligned two-column table, sorted by name.
pub fn format_table(metrics: &HashMap<String, f64>) -> String {
    let mut rows: Vec<(&String, &f64)> = metrics.iter().collect();
    rows.sort_by(|a, b| a.0.cmp(b.0));
    let width = rows.iter().map(|(k, _)| k.len()).max().unwrap_or(6).max(6);
    let mut out = format!("{:<width$}  value\n", "metric");
    for (k, v) in rows {
        let value = if v.fract() == 0.0 && v.abs() < 1e12 {
            format!("{v:.0}")
        } else {
            format!("{v:.4}")
        };
        out.push_str(&format!("{k:<width$}  {value}\n"));
    }
    out
}

/// `unigait eval`: print the metrics table (and the JSON report with `--json`).
pub async fn run_eval(client: &mut Client, token: Option<&str>, args: &EvalArgs) -> Result<()> {
    let message = request(
        &args.policy,
        args.biped_policy.as_deref(),
        &args.scenario,
        args.envs,
        args.seed,
        false,
    )?;
    let reply = evaluate(client, token, message)
        .await
        .with_context(|| format!("evaluating on `{}`", args.scenario))?;
    let table = format_table(&reply.metrics);
    if args.json {
        eprint!("{table}");
        println!("{}", reply.report_json);
    } else {
        print!("{table}");
    }
    Ok(())
}

/// `unigait record`: write the recording to `--out` and print the metrics table.
pub async fn run_record(client: &mut Client, token: Option<&str>, args: &RecordArgs) -> Result<()> {
    let message = request(
        &args.policy,
        args.biped_policy.as_deref(),
        &args.scenario,
        args.envs,
        args.seed,
        true,
    )?;
    let reply = evaluate(client, token, message)
        .await
        .with_context(|| format!("recording `{}`", args.scenario))?;
    if reply.recording_rrd.is_empty() {
        anyhow::bail!("the server sent no recording");
    }
    std::fs::write(&args.out, &reply.recording_rrd)
        .with_context(|| format!("cannot write `{}`", args.out.display()))?;
    print!("{}", format_table(&reply.metrics));
    eprintln!(
        "wrote {} ({} bytes): open it with `rerun {}`",
        args.out.display(),
        reply.recording_rrd.len(),
        args.out.display()
    );
    Ok(())
}

#[cfg(test)]
mod test {
    use super::*;

    #[test]
    fn table_is_sorted_and_aligned() {
        let metrics = HashMap::from([
            ("trials".to_string(), 20.0),
            ("success_rate".to_string(), 0.95),
        ]);
        let t = format_table(&metrics);
        let lines: Vec<&str> = t.lines().collect();
        assert_eq!(lines[1], "success_rate  0.9500");
        assert_eq!(lines[2], "trials        20");
    }
}
