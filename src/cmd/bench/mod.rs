//! `stillpoint bench`: one module per benchmark.

#[derive(clap::Subcommand)]
pub enum BenchCommand {
    /// Feature front-end speed (ORB, Harris, LK).
    Features(NotYet),
}

#[derive(clap::Args)]
pub struct NotYet {}

pub fn run(_cmd: BenchCommand) -> anyhow::Result<()> {
    anyhow::bail!("not implemented yet")
}
