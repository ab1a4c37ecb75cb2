//! Checks on a session's TOML overrides: their shape before parsing (length, nesting: a deep
//! document would recurse the parser off its stack) and the cost of the config they make.

use unigait_sim::task::TaskConfig;

use crate::error::ServiceError;
use crate::limits::{CostCaps, Limits};

/// The task config a request's TOML overrides make from `base` (`base` itself when they are
/// blank), after the checks on their shape and on the cost of the result. `field` names the
/// request field in errors.
pub fn apply(
    base: &TaskConfig,
    text: &str,
    field: &str,
    limits: &Limits,
) -> Result<TaskConfig, ServiceError> {
    let task = if text.trim().is_empty() {
        base.clone()
    } else {
        check_shape(text, field, limits)?;
        base.with_overrides(text)?
    };
    check_costs(&task, &limits.cost)?;
    Ok(task)
}

/// Refuse overrides longer than the limit or nested deeper than it. The scan is conservative:
/// it counts the brackets and braces open at once and the dots of a dotted key or a table
/// header, outside strings and comments.
fn check_shape(text: &str, field: &str, limits: &Limits) -> Result<(), ServiceError> {
    if text.len() > limits.max_overrides_bytes {
        return Err(ServiceError::InvalidArgument(format!(
            "{field} has {} bytes; this server takes at most {}",
            text.len(),
            limits.max_overrides_bytes
        )));
    }
    let depth = nesting_depth(text);
    if depth > limits.max_overrides_depth {
        return Err(ServiceError::InvalidArgument(format!(
            "{field} nests {depth} levels deep; the task config has at most {} \
             (tables, arrays and dotted keys count)",
            limits.max_overrides_depth
        )));
    }
    Ok(())
}

/// The deepest nesting in `text`: open brackets and braces plus the dots of the key being
/// read (a dotted key or table header nests one table per dot), outside strings and comments.
fn nesting_depth(text: &str) -> usize {
    let mut deepest = 0usize;
    // The brackets and braces open, innermost last.
    let mut open: Vec<char> = Vec::new();
    // Dots of the key being read, and whether a value (not a key) is being read.
    let mut dots = 0usize;
    let mut in_value = false;
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        match c {
            '#' => {
                for s in chars.by_ref() {
                    if s == '\n' {
                        break;
                    }
                }
                (dots, in_value) = (0, false);
            }
            '\n' => (dots, in_value) = (0, false),
            '=' => in_value = true,
            '[' => open.push(c),
            '{' => {
                open.push(c);
                (dots, in_value) = (0, false);
            }
            ']' | '}' => {
                open.pop();
            }
            ',' if open.last() == Some(&'{') => (dots, in_value) = (0, false),
            '.' if !in_value => dots += 1,
            '"' | '\'' => {
                // Skip the string (basic strings honour backslash escapes; a multi-line string
                // is skipped as a run of one-line strings, conservative enough here).
                let quote = c;
                while let Some(s) = chars.next() {
                    if quote == '"' && s == '\\' {
                        chars.next();
                    } else if s == quote || s == '\n' {
                        break;
                    }
                }
            }
            _ => {}
        }
        deepest = deepest.max(open.len() + dots);
    }
    deepest
}

fn over(field: &str, value: impl std::fmt::Display, cap: impl std::fmt::Display) -> ServiceError {
    ServiceError::LimitExceeded(format!(
        "`{field}` = {value} is over this server's cost cap of {cap} (one step must not hold the shared workers for long)"
    ))
}

/// Refuse a config whose settings make steps costlier than the server's caps allow.
fn check_costs(task: &TaskConfig, caps: &CostCaps) -> Result<(), ServiceError> {
    let (p, e) = (&task.physics, &task.env);
    let counts = [
        ("env.decimation", e.decimation, caps.max_decimation),
        (
            "physics.solver_iterations",
            p.solver_iterations,
            caps.max_solver_iterations,
        ),
        (
            "physics.pgs_iterations",
            p.pgs_iterations,
            caps.max_pgs_iterations,
        ),
        (
            "physics.extra_iterations_on_leg_contact",
            p.extra_iterations_on_leg_contact,
            caps.max_extra_iterations,
        ),
        (
            "physics.extra_pgs_iterations_on_leg_contact",
            p.extra_pgs_iterations_on_leg_contact,
            caps.max_extra_pgs_iterations,
        ),
        (
            "env.envs_per_world",
            e.envs_per_world,
            caps.max_envs_per_world,
        ),
    ];
    for (field, value, cap) in counts {
        if value > cap {
            return Err(over(field, value, cap));
        }
    }
    let min_dt = caps.min_physics_dt_us as f32 * 1e-6;
    if p.dt < min_dt {
        return Err(ServiceError::LimitExceeded(format!(
            "`physics.dt` = {} is below this server's floor of {min_dt} s (more physics steps per simulated second)",
            p.dt
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_counts_brackets_and_dotted_keys_not_strings() {
        assert_eq!(nesting_depth("[rewards]\ntask_indicators = false\n"), 1);
        assert_eq!(nesting_depth("a.b.c = 1"), 2);
        assert_eq!(nesting_depth("x = \"[[[[[[[[[[\""), 0);
        assert_eq!(nesting_depth("x = [[[[1]]]]"), 4);
        assert_eq!(nesting_depth("# [[[[[[\nx = 1"), 0);
        assert_eq!(
            nesting_depth("[gait]\noffsets_quad = [0.0, 0.5, 0.5, 0.0, 0.1, 0.2, 0.3]"),
            1
        );
        assert!(nesting_depth(&format!("x = {{{} = 1}}", vec!["a"; 100].join("."))) > 99);
        assert!(nesting_depth(&"[".repeat(100_000)) >= 100_000);
    }
}
