//! `stillpoint eval`: trajectory metrics.

#[derive(clap::Subcommand)]
pub enum EvalCommand {
    /// Absolute trajectory error.
    Ate(NotYet),
}

#[derive(clap::Args)]
pub struct NotYet {}

pub fn run(_cmd: EvalCommand) -> anyhow::Result<()> {
    anyhow::bail!("not implemented yet")
}
