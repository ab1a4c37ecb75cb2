//! Errors at the core's boundaries (files, configs, requests). The step itself never fails:
//! a broken env is reset and counted instead.

use thiserror::Error;

/// Everything that can go wrong when building or driving the simulation.
#[derive(Debug, Error)]
pub enum SimError {
    /// A file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The path that failed.
        path: String,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The robot description is malformed or unsupported.
    #[error("robot description: {0}")]
    Urdf(String),
    /// The robot config does not fit the robot description.
    #[error("robot config: {0}")]
    Robot(String),
    /// A config value is out of its allowed range.
    #[error("config `{field}` = {value}: {allowed}")]
    InvalidConfig {
        /// Dotted path of the field, e.g. `rewards.weights.collision`.
        field: String,
        /// The rejected value, printed.
        value: String,
        /// What is allowed.
        allowed: String,
    },
    /// A config document could not be parsed.
    #[error("config: {0}")]
    ConfigSyntax(String),
    /// A request's tensor has the wrong size.
    #[error("`{name}` has {got} values, expected {expected} ({detail})")]
    Shape {
        /// Tensor name.
        name: String,
        /// Number of values received.
        got: usize,
        /// Number of values expected.
        expected: usize,
        /// How the expected size is made up.
        detail: String,
    },
    /// A request holds a NaN or infinite value.
    #[error("`{name}` holds a non-finite value at index {index} (env {env}): {value}")]
    NonFinite {
        /// Tensor name.
        name: String,
        /// Flat index of the first bad value.
        index: usize,
        /// The env it belongs to.
        env: usize,
        /// The value.
        value: f32,
    },
}

impl SimError {
    /// Shorthand for [`SimError::InvalidConfig`].
    pub fn invalid(
        field: impl Into<String>,
        value: impl std::fmt::Display,
        allowed: impl Into<String>,
    ) -> Self {
        SimError::InvalidConfig {
            field: field.into(),
            value: value.to_string(),
            allowed: allowed.into(),
        }
    }
}
