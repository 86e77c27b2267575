//! `pcuvd simulate`: RF recordings of flow phantoms, conventional and Hadamard-coded, with ground
//! truth, written as recording manifests. The settings and the simulation are the application
//! layer's ([`pcuvd_app::simulation`]).

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use pcuvd_app::simulation::{Simulation, SimulationSettings};

use crate::progress::bar;

/// Arguments of `pcuvd simulate`.
#[derive(Args, Debug)]
pub struct SimulateArgs {
    /// What to simulate.
    #[command(flatten)]
    pub options: SimulationSettings,
    /// Output folder (created if needed).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `pcuvd simulate`.
pub fn run(args: &SimulateArgs) -> Result<()> {
    let simulation = Simulation::new(&args.options)?;
    let total: usize = simulation
        .modes
        .iter()
        .map(|(_, p)| simulation.frames * p.sequence.n_angles())
        .sum();
    let names: Vec<&str> = simulation.modes.iter().map(|(name, _)| *name).collect();
    let progress = bar(&format!("simulate {}", names.join(" + ")), total as u64);
    pcuvd_app::simulation::folder::write(
        &simulation,
        &args.out,
        &|done, _| progress.set_position(done as u64),
        &|line| println!("{line}"),
    )?;
    progress.finish();
    Ok(())
}
