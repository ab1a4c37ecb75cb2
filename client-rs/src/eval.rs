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
use unigait_proto::v1;

use crate::Client;

/// The policy, scenario and envs an evaluation runs.
#[derive(Clone, Debug, clap::Args)]
pub struct RolloutArgs {
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
}

/// `unigait eval`: evaluate a policy and print its metrics.
#[derive(Clone, Debug, clap::Args)]
pub struct EvalArgs {
    /// What to evaluate.
    #[command(flatten)]
    pub rollout: RolloutArgs,
    /// Print the full JSON report on stdout (the table goes to stderr).
    #[arg(long)]
    pub json: bool,
}

/// `unigait record`: evaluate a policy and save a rerun recording of env 0.
#[derive(Clone, Debug, clap::Args)]
pub struct RecordArgs {
    /// What to evaluate.
    #[command(flatten)]
    pub rollout: RolloutArgs,
    /// Where to write the recording (open it with `rerun rollout.rrd`).
    #[arg(long)]
    pub out: PathBuf,
}

fn read_policy(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).with_context(|| format!("cannot read policy `{}`", path.display()))
}

/// An Evaluate request from policy files.
pub fn request(args: &RolloutArgs, record: bool) -> Result<v1::EvaluateRequest> {
    Ok(v1::EvaluateRequest {
        policy_onnx: read_policy(&args.policy)?.into(),
        biped_policy_onnx: match &args.biped_policy {
            Some(p) => read_policy(p)?.into(),
            None => Default::default(),
        },
        scenario: args.scenario.clone(),
        num_envs: args.envs,
        seed: args.seed,
        record,
    })
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
pub async fn run_eval(client: &mut Client, args: &EvalArgs) -> Result<()> {
    let reply = client
        .evaluate(request(&args.rollout, false)?)
        .await
        .with_context(|| format!("evaluating on `{}`", args.rollout.scenario))?;
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
pub async fn run_record(client: &mut Client, args: &RecordArgs) -> Result<()> {
    let reply = client
        .evaluate(request(&args.rollout, true)?)
        .await
        .with_context(|| format!("recording `{}`", args.rollout.scenario))?;
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
