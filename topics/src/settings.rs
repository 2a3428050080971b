//! The processes' settings files: one error type naming the key and the reason, and the TOML
//! parsing every process shares (unknown keys refused).

use serde::de::DeserializeOwned;

use crate::channel::WaitStrategy;

/// A setting that is out of range or unreadable, named by its key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{process} setting `{key}`: {reason}")]
pub struct SettingError {
    /// Which process's settings ("controller", "perception").
    pub process: &'static str,
    /// The TOML key (`(file)` when the document itself does not parse).
    pub key: &'static str,
    /// What is wrong.
    pub reason: String,
}

impl SettingError {
    /// An error for `key` of `process`.
    pub fn new(process: &'static str, key: &'static str, reason: impl Into<String>) -> Self {
        Self {
            process,
            key,
            reason: reason.into(),
        }
    }
}

/// Parses a TOML document into `T` (whose serde attributes refuse unknown keys).
pub fn parse<T: DeserializeOwned>(process: &'static str, text: &str) -> Result<T, SettingError> {
    toml::from_str(text).map_err(|e| SettingError::new(process, "(file)", e.to_string()))
}

/// Parses the `wait` key's value.
pub fn wait_strategy(process: &'static str, text: &str) -> Result<WaitStrategy, SettingError> {
    text.parse().map_err(|e: crate::channel::BadWaitStrategy| {
        SettingError::new(process, "wait", e.to_string())
    })
}
