//! The whole-recording run: form the images, then analyse them.

use crate::acquisition::channel::ChannelData;

use super::analyse::{analyse, check_doppler_estimator};
use super::form::form_images;
use super::params::{ProcessOutput, ProcessParams, Stage};
use crate::core::error::Result;

/// Runs the pipeline on a recording. `progress(stage, done, total)` is called as work completes.
pub fn process(
    data: &ChannelData,
    params: &ProcessParams,
    progress: &dyn Fn(Stage, usize, usize),
) -> Result<ProcessOutput> {
    check_doppler_estimator(&data.acquisition, params)?;
    let (images, mut timings) = form_images(data, params, progress)?;
    let mut out = analyse(images, params, progress)?;
    timings.append(&mut out.timings);
    out.timings = timings;
    Ok(out)
}
