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

/// Checks a CPU-placement key (`acting_cpu`, …): unset, or a CPU this process may run on.
pub fn cpu(
    process: &'static str,
    key: &'static str,
    cpu: Option<usize>,
) -> Result<(), SettingError> {
    match cpu {
        None => Ok(()),
        Some(c) => crate::affinity::check_cpu(c)
            .map_err(|e| SettingError::new(process, key, e.to_string())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Demo {
        rate: u32,
    }

    #[test]
    fn a_bad_document_names_the_file_and_the_parsers_reason() {
        assert_eq!(parse::<Demo>("demo", "rate = 5"), Ok(Demo { rate: 5 }));
        for (text, reason) in [
            ("rate = 5\nrat = 6", "rat"),        // unknown key
            ("rate = \"fast\"", "rate"),         // wrong type
            ("rate = 5\nrate = 6", "duplicate"), // a key twice
            ("rate = ", "rate"),                 // truncated
            ("", "rate"),                        // a required key missing
        ] {
            let err = parse::<Demo>("demo", text).expect_err(text);
            assert_eq!((err.process, err.key), ("demo", "(file)"), "{text}");
            assert!(err.reason.contains(reason), "{text}: {err}");
            assert!(
                err.to_string().starts_with("demo setting `(file)`: "),
                "{err}"
            );
        }
    }

    #[test]
    fn a_cpu_key_is_unset_or_an_allowed_cpu() {
        assert_eq!(cpu("demo", "acting_cpu", None), Ok(()));
        let allowed = crate::affinity::allowed_cpus();
        if let Some(&c) = allowed.first() {
            assert_eq!(cpu("demo", "acting_cpu", Some(c)), Ok(()));
        }
        let err = cpu("demo", "acting_cpu", Some(100_000)).expect_err("no such CPU");
        assert_eq!((err.process, err.key), ("demo", "acting_cpu"));
        assert!(err.reason.contains("100000"), "{err}");
    }

    #[test]
    fn a_bad_wait_strategy_names_the_wait_key() {
        assert_eq!(wait_strategy("demo", "spin"), Ok(WaitStrategy::Spin));
        for bad in ["nap", "spin-then-block:0", "spin-then-block:x", ""] {
            let err = wait_strategy("demo", bad).expect_err(bad);
            assert_eq!((err.process, err.key), ("demo", "wait"), "{bad}");
            assert!(!err.reason.is_empty());
        }
    }
}
