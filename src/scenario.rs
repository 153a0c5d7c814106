//! Scenario files (TOML): schema, validation and `--set` overrides.
