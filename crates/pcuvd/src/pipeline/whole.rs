//! The whole-recording run: form the images a block of frames at a time, cut the Doppler time
//! series when asked, then analyse the whole series. The one sequence every front end's run of a
//! recording held whole follows; [`process`] is its simplest case.

use std::time::Instant;

use crate::acquisition::channel::ChannelData;
use crate::acquisition::source::FrameSource;
use crate::core::error::Result;

use super::analyse::{analyse, check_doppler_estimator};
use super::blocks::Blocks;
use super::ensembles::{EnsembleMaps, EnsembleSpec, ensemble_maps};
use super::form::form_images_in_blocks;
use super::params::{ProcessOutput, ProcessParams, Stage};

/// Runs the chain on the recording `source`: its images formed in `blocks`, the Doppler time
/// series of `ensembles` when asked (each ensemble filtered on its own, from the unfiltered
/// images), then the analysis of the whole series. `progress(stage, done, total)` is called as
/// work completes; the output's timings cover every stage.
pub fn process_source(
    source: &dyn FrameSource,
    params: &ProcessParams,
    blocks: Blocks,
    ensembles: Option<EnsembleSpec>,
    progress: &dyn Fn(Stage, usize, usize),
) -> Result<(ProcessOutput, Option<EnsembleMaps>)> {
    let (images, mut timings) = form_images_in_blocks(source, params, blocks, progress)?;
    let ensembles = match ensembles {
        None => None,
        Some(spec) => {
            let clock = Instant::now();
            let maps = ensemble_maps(&images, params, spec, progress)?;
            timings.push((Stage::Ensembles, clock.elapsed().as_secs_f64()));
            Some(maps)
        }
    };
    let mut out = analyse(images, params, progress)?;
    timings.append(&mut out.timings);
    out.timings = timings;
    Ok((out, ensembles))
}

/// Runs the pipeline on a recording held in memory, as one block, without a time series.
/// `progress(stage, done, total)` is called as work completes.
pub fn process(
    data: &ChannelData,
    params: &ProcessParams,
    progress: &dyn Fn(Stage, usize, usize),
) -> Result<ProcessOutput> {
    check_doppler_estimator(&data.acquisition, params)?;
    data.validate()?;
    let whole = Blocks::whole(data.n_frames());
    Ok(process_source(data, params, whole, None, progress)?.0)
}
