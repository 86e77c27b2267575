//! The memory check before work: a run that would need more than the machine (or the user's
//! limit) allows is refused with the amount it needs, instead of aborting on allocation.

use anyhow::{Result, bail};
use pcuvd::acquisition::source::FrameSource;
use pcuvd::pipeline;

use crate::run::Plan;

/// How [`check_memory`] counts beyond [`pipeline::MEMORY_ESTIMATE_RULE`].
pub const STAGE_MEMORY_RULE: &str = "+ dynamics: 5 × windows × pixels × 8 bytes (vx, vz, power, \
speed and the pooled speed per window) + time series: ensembles × pixels × 6 × 8 bytes (five \
maps and a filtered copy of one ensemble's frames per angle counted once more)";

/// Bytes the stages after image formation hold beyond the chain's image series
/// ([`STAGE_MEMORY_RULE`]): the dynamics stage's window series and a time series' maps.
fn stage_memory(data: &dyn FrameSource, plan: &Plan) -> u128 {
    let (nz, nx) = plan.params.grid.shape();
    let pixels = (nz * nx) as u128;
    let frames = data.n_frames();
    // The stage runs only with two angles or more and a window the recording holds.
    let vectors = data.acquisition().sequence.n_angles() >= 2;
    let dynamics = plan.dynamics.as_ref().map_or(0, |d| {
        if !vectors || d.params.window > frames {
            return 0;
        }
        let windows = (frames - d.params.window) / d.params.step.max(1) + 1;
        5 * windows as u128 * pixels * 8
    });
    let ensembles = plan.ensembles.map_or(0, |e| {
        let count = frames.saturating_sub(e.frames) / e.step.max(1) + 1;
        let angles = data.acquisition().sequence.n_angles() as u128;
        count as u128 * pixels * 6 * 8 + e.frames as u128 * pixels * angles * 8
    });
    dynamics + ensembles
}

/// Refuses, before any work, a recording, grid and stages whose processing would need more memory
/// than the machine has available ([`pipeline::memory_estimate`] + [`STAGE_MEMORY_RULE`]),
/// instead of aborting on allocation.
pub fn check_memory(data: &dyn FrameSource, plan: &Plan, limit_gb: Option<f64>) -> Result<()> {
    let params = &plan.params;
    let available = match limit_gb {
        Some(gb) if gb.is_finite() && gb > 0.0 => Some(gb * 1e9),
        Some(gb) => bail!(
            "--max-memory-gb {}: must be a positive number of GB",
            crate::settings::shown("--max-memory-gb", gb)
        ),
        None => available_memory().map(|b| b as f64),
    };
    let needed = (pipeline::memory_estimate(data, &params.grid) + stage_memory(data, plan)) as f64;
    if let Some(available) = available
        && needed > available
    {
        let what = match limit_gb {
            Some(gb) => format!(
                "--max-memory-gb {}",
                crate::settings::shown("--max-memory-gb", gb)
            ),
            None => "the machine".to_string(),
        };
        bail!(
            "processing needs about {:.3} GB ({} {STAGE_MEMORY_RULE}) but {:.3} GB are \
             available ({what}): use a coarser or smaller --grid, or a shorter recording",
            needed / 1e9,
            pipeline::MEMORY_ESTIMATE_RULE,
            available / 1e9
        );
    }
    Ok(())
}

/// Memory available to a new process (bytes): `MemAvailable` of /proc/meminfo, where there is one.
pub fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}
