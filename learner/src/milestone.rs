//! Milestones as data (`assets/milestones.toml`, shared with the Python learner's
//! `unigait.milestones`): the checks a recipe stage stops on once its policy meets them on the
//! validation seed. One metric of one scenario's evaluation against a bound; `extends` takes
//! another milestone's scenarios and checks first; a group passes when `at_least` of its checks
//! do.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use serde::Deserialize;
use unigait_client::{Client, v1};

use crate::{Error, Result};

/// Scenario -> metric -> value.
pub type Evals = BTreeMap<String, BTreeMap<String, f64>>;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCheck {
    label: String,
    scenario: String,
    metric: String,
    op: String,
    bound: f64,
    #[serde(default)]
    group: Option<String>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawGroup {
    at_least: usize,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMilestone {
    #[serde(default)]
    description: String,
    #[serde(default)]
    extends: Option<String>,
    #[serde(default)]
    scenarios: Vec<String>,
    #[serde(default)]
    checks: Vec<RawCheck>,
    #[serde(default)]
    groups: BTreeMap<String, RawGroup>,
    #[serde(default)]
    num_envs: BTreeMap<String, u32>,
}

/// One criterion: `metric` of `scenario`'s report compared with `bound`.
#[derive(Debug, Clone, PartialEq)]
pub struct Check {
    /// The scenario.
    pub scenario: String,
    /// The metric of its report.
    pub metric: String,
    /// `<=` or `>=`.
    pub op: String,
    /// The bound.
    pub bound: f64,
    /// What it is called.
    pub label: String,
    /// The group it counts in.
    pub group: Option<String>,
}

impl Check {
    pub(crate) fn value(&self, evals: &Evals) -> Option<f64> {
        evals.get(&self.scenario)?.get(&self.metric).copied()
    }

    pub(crate) fn passes(&self, value: Option<f64>) -> bool {
        match value {
            None => false,
            Some(v) if self.op == "<=" => v <= self.bound,
            Some(v) => v >= self.bound,
        }
    }

    /// How far `value` clears the bound, relative to it, clipped to [-1, 1] (missing: -1), as
    /// the Python learner's `Check.margin`.
    fn margin(&self, value: Option<f64>) -> f64 {
        let Some(v) = value else { return -1.0 };
        let relative = if self.bound == 0.0 {
            v
        } else {
            (v - self.bound) / self.bound.abs()
        };
        let relative = if self.op == "<=" { -relative } else { relative };
        relative.clamp(-1.0, 1.0)
    }
}

/// A named set of checks and the scenarios they need.
#[derive(Debug, Clone, PartialEq)]
pub struct Milestone {
    /// Its name.
    pub name: String,
    /// Its description.
    pub description: String,
    /// Scenarios to evaluate.
    pub scenarios: Vec<String>,
    /// The checks (the extended milestone's first).
    pub checks: Vec<Check>,
    /// Group -> checks of it that must pass.
    pub groups: BTreeMap<String, usize>,
    /// Scenario -> envs it is always evaluated with.
    pub num_envs: BTreeMap<String, u32>,
}

impl Milestone {
    /// Envs `scenario` is evaluated with.
    pub fn envs_for(&self, scenario: &str, default: u32) -> u32 {
        self.num_envs.get(scenario).copied().unwrap_or(default)
    }

    /// Criteria: each ungrouped check, and each group as one.
    pub fn criteria(&self) -> usize {
        self.checks.iter().filter(|c| c.group.is_none()).count() + self.groups.len()
    }

    /// Criteria met.
    pub fn score(&self, evals: &Evals) -> usize {
        let mut met = 0;
        let mut passed: HashMap<&str, usize> = HashMap::new();
        for c in &self.checks {
            let ok = c.passes(c.value(evals));
            match &c.group {
                None => met += usize::from(ok),
                Some(g) => *passed.entry(g).or_default() += usize::from(ok),
            }
        }
        met + self
            .groups
            .iter()
            .filter(|(g, need)| passed.get(g.as_str()).copied().unwrap_or(0) >= **need)
            .count()
    }

    /// Every check's margin, summed: how a selection ranks checkpoints that meet as many
    /// criteria (clipped per check, so one runaway figure does not outvote the others).
    pub fn margin(&self, evals: &Evals) -> f64 {
        self.checks.iter().map(|c| c.margin(c.value(evals))).sum()
    }

    /// Whether every criterion is met.
    pub fn met(&self, evals: &Evals) -> bool {
        self.score(evals) == self.criteria()
    }

    /// The criteria not met, each with its figures (`quad yaw-rate error 0.226 (needs <= 0.2)`);
    /// a group that falls short is one entry. The Python learner's rows say the same.
    pub fn unmet(&self, evals: &Evals) -> Vec<String> {
        let mut out = Vec::new();
        let mut short: BTreeMap<&str, Vec<String>> = self
            .groups
            .keys()
            .map(|g| (g.as_str(), Vec::new()))
            .collect();
        for c in &self.checks {
            let value = c.value(evals);
            if c.passes(value) {
                continue;
            }
            let shown = value.map_or_else(|| "missing".to_string(), figure);
            let failing = format!("{} {shown} (needs {} {})", c.label, c.op, figure(c.bound));
            match &c.group {
                None => out.push(failing),
                Some(g) => short.entry(g.as_str()).or_default().push(failing),
            }
        }
        for (group, need) in &self.groups {
            let size = self
                .checks
                .iter()
                .filter(|c| c.group.as_deref() == Some(group.as_str()))
                .count();
            let failing = short.remove(group.as_str()).unwrap_or_default();
            let passed = size - failing.len();
            if passed < *need {
                out.push(format!(
                    "{group}: {passed} of {size}, needs {need}: {}",
                    failing.join("; ")
                ));
            }
        }
        out
    }
}

/// `value` to 3 decimals without trailing zeros (`0.226`, `1`).
fn figure(value: f64) -> String {
    let text = format!("{value:.3}");
    text.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// The milestones file: `$UNIGAIT_MILESTONES`, else the repository's `assets/milestones.toml`.
pub fn milestones_file() -> PathBuf {
    if let Some(p) = std::env::var_os("UNIGAIT_MILESTONES") {
        return PathBuf::from(p);
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/milestones.toml")
}

/// Milestone `name` of the file at `path`.
pub fn load_milestone(name: &str, path: &Path) -> Result<Milestone> {
    let text = std::fs::read_to_string(path)?;
    let doc: BTreeMap<String, RawMilestone> = toml::from_str(&text)
        .map_err(|e| Error::Run(format!("{}: {}", path.display(), e.message())))?;
    build(&doc, name, &mut Vec::new(), &path.display().to_string())
}

fn build(
    doc: &BTreeMap<String, RawMilestone>,
    name: &str,
    seen: &mut Vec<String>,
    source: &str,
) -> Result<Milestone> {
    if seen.iter().any(|s| s == name) {
        return Err(Error::Run(format!("{source}: [{name}] extends itself")));
    }
    let raw = doc.get(name).ok_or_else(|| {
        Error::Run(format!(
            "unknown milestone {name:?}; known: {:?}",
            doc.keys().collect::<Vec<_>>()
        ))
    })?;
    seen.push(name.to_string());
    let mut m = match &raw.extends {
        Some(base) => build(doc, base, seen, source)?,
        None => Milestone {
            name: String::new(),
            description: String::new(),
            scenarios: Vec::new(),
            checks: Vec::new(),
            groups: BTreeMap::new(),
            num_envs: BTreeMap::new(),
        },
    };
    m.name = name.to_string();
    m.description = raw.description.clone();
    for (g, v) in &raw.groups {
        m.groups.insert(g.clone(), v.at_least);
    }
    for s in &raw.scenarios {
        if !m.scenarios.contains(s) {
            m.scenarios.push(s.clone());
        }
    }
    for (i, c) in raw.checks.iter().enumerate() {
        let here = format!("{source}: [{name}] check {}", i + 1);
        if c.op != "<=" && c.op != ">=" {
            return Err(Error::Run(format!(
                "{here}: op must be '<=' or '>=', got {:?}",
                c.op
            )));
        }
        if let Some(g) = &c.group
            && !m.groups.contains_key(g)
        {
            return Err(Error::Run(format!(
                "{here}: group {g:?} is not in the milestone's groups"
            )));
        }
        if !m.scenarios.contains(&c.scenario) {
            return Err(Error::Run(format!(
                "{here}: scenario {:?} is not in its scenarios",
                c.scenario
            )));
        }
        m.checks.push(Check {
            scenario: c.scenario.clone(),
            metric: c.metric.clone(),
            op: c.op.clone(),
            bound: c.bound,
            label: c.label.clone(),
            group: c.group.clone(),
        });
    }
    for (s, n) in &raw.num_envs {
        m.num_envs.insert(s.clone(), *n);
    }
    Ok(m)
}

/// Evaluate `policy_onnx` on every scenario of `milestone` (`envs` each, unless the milestone
/// fixes them) on `seed`, on the server `client` talks to, with the task overrides
/// `task_overrides_toml` (the training engine's).
pub async fn evaluate(
    client: &mut Client,
    milestone: &Milestone,
    policy_onnx: &[u8],
    envs: u32,
    seed: u64,
    task_overrides_toml: &str,
) -> Result<Evals> {
    let sized = |scenario: &str| milestone.envs_for(scenario, envs);
    evaluate_sized(
        client,
        milestone,
        policy_onnx,
        &sized,
        seed,
        task_overrides_toml,
    )
    .await
}

/// Every scenario of `milestone` on `envs` envs, Table VI's too (its sizes ignored): the many
/// trials a pass chance is estimated from.
pub async fn evaluate_at(
    client: &mut Client,
    milestone: &Milestone,
    policy_onnx: &[u8],
    envs: u32,
    seed: u64,
    task_overrides_toml: &str,
) -> Result<Evals> {
    let every = |_: &str| envs;
    evaluate_sized(
        client,
        milestone,
        policy_onnx,
        &every,
        seed,
        task_overrides_toml,
    )
    .await
}

async fn evaluate_sized(
    client: &mut Client,
    milestone: &Milestone,
    policy_onnx: &[u8],
    envs: &(dyn Fn(&str) -> u32 + Sync),
    seed: u64,
    task_overrides_toml: &str,
) -> Result<Evals> {
    let mut evals = Evals::new();
    for scenario in &milestone.scenarios {
        let r = client
            .evaluate(v1::EvaluateRequest {
                policy_onnx: policy_onnx.to_vec().into(),
                scenario: scenario.clone(),
                num_envs: envs(scenario),
                seed,
                task_overrides_toml: task_overrides_toml.to_string(),
                ..Default::default()
            })
            .await?;
        evals.insert(scenario.clone(), r.metrics.into_iter().collect());
    }
    Ok(evals)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn evals(pairs: &[(&str, &str, f64)]) -> Evals {
        let mut e = Evals::new();
        for (s, m, v) in pairs {
            e.entry(s.to_string())
                .or_default()
                .insert(m.to_string(), *v);
        }
        e
    }

    #[test]
    fn m1_is_three_bounds_on_tracking_quad() {
        let m1 = load_milestone("M1", &milestones_file()).unwrap();
        assert_eq!(m1.scenarios, ["tracking_quad"]);
        assert_eq!(m1.criteria(), 3);
        let good = evals(&[
            ("tracking_quad", "tracking/quad/lin_vel_error_mps", 0.15),
            ("tracking_quad", "tracking/quad/ang_vel_error_radps", 0.1),
            ("tracking_quad", "tracking/quad/termination_rate", 0.0),
        ]);
        assert!(m1.met(&good) && m1.unmet(&good).is_empty());
        let slow = evals(&[
            ("tracking_quad", "tracking/quad/lin_vel_error_mps", 0.151),
            ("tracking_quad", "tracking/quad/ang_vel_error_radps", 0.1),
            ("tracking_quad", "tracking/quad/termination_rate", 0.0),
        ]);
        assert_eq!(m1.score(&slow), 2);
        assert!(!m1.met(&slow));
        assert_eq!(
            m1.unmet(&slow),
            ["quad lin. vel. error 0.151 (needs <= 0.15)"]
        );
        // A missing metric does not pass.
        assert_eq!(m1.score(&evals(&[])), 0);
        // Margins relative to each bound, clipped to [-1, 1]; a missing metric counts -1.
        let mixed = evals(&[
            ("tracking_quad", "tracking/quad/lin_vel_error_mps", 0.12),
            ("tracking_quad", "tracking/quad/ang_vel_error_radps", 0.5),
            ("tracking_quad", "tracking/quad/termination_rate", 0.0),
        ]);
        // +0.2, (0.2 - 0.5) / 0.2 = -1.5 clipped to -1, and +1 (0.05 - 0) / 0.05.
        assert!(
            (m1.margin(&mixed) - 0.2).abs() < 1e-12,
            "{}",
            m1.margin(&mixed)
        );
        assert_eq!(m1.margin(&evals(&[])), -3.0);
    }

    /// M3 extends M2 (which extends M1) and counts Table VI as one group of 4 of 6.
    #[test]
    fn extends_and_groups() {
        let m3 = load_milestone("M3", &milestones_file()).unwrap();
        assert_eq!(m3.scenarios[0], "tracking_quad");
        assert!(m3.scenarios.contains(&"table_vi".to_string()));
        assert_eq!(m3.groups["table_vi"], 4);
        assert_eq!(m3.envs_for("table_vi", 64), 20);
        let m2 = load_milestone("M2", &milestones_file()).unwrap();
        assert_eq!(m3.criteria(), m2.criteria() + 1);
        // Table VI short of its group, in the Python learner's words.
        let columns = evals(&[
            ("table_vi", "stairs_up_quad/success_rate", 0.0),
            ("table_vi", "stairs_down_quad/success_rate", 1.0),
            ("table_vi", "slope_quad/success_rate", 0.9),
            ("table_vi", "slope_biped/success_rate", 0.7),
            ("table_vi", "stairs_up_biped/success_rate", 0.55),
            ("table_vi", "stairs_down_biped/success_rate", 1.0),
        ]);
        let unmet = m3.unmet(&columns);
        assert_eq!(unmet.len(), m2.criteria() + 1, "{unmet:?}");
        assert_eq!(
            unmet[unmet.len() - 1],
            "table_vi: 2 of 6, needs 4: 15 cm stairs up (q) 0 (needs >= 1); 30 deg slope (q) \
             0.9 (needs >= 1); 30 deg slope (b) 0.7 (needs >= 1); 12 cm stairs up (b) 0.55 \
             (needs >= 0.6)"
        );
        assert_eq!(unmet[0], "quad lin. vel. error missing (needs <= 0.15)");
    }
}
