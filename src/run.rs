//! Scenario runs (in progress).
pub fn run_cli(_: &std::path::Path, _: Option<&std::path::Path>, _: Option<f64>, _: &[String], _: bool) -> anyhow::Result<()> {
    anyhow::bail!("not implemented")
}
