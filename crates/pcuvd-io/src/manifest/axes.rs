//! The axes of a manifest's samples (`[data].axes`): their canonical order in each version, the
//! permutation that brings named axes into it, and the (events, channels, samples) shape checked
//! against the acquisition.

use std::path::Path;

use ndarray::{Array3, ArrayD};
use pcuvd::Acquisition;

use crate::error::IoError;

/// (events, channels, samples) of samples of `shape` whose axes are `axes`, checked against the
/// acquisition: angles and elements.
pub(crate) fn event_shape(
    path: &Path,
    acquisition: &Acquisition,
    data_path: &Path,
    axes: &[String],
    perm: &[usize],
    shape: &[usize],
) -> Result<(usize, usize, usize), IoError> {
    if shape.len() != axes.len() {
        return Err(IoError::invalid(
            path,
            "[data].axes",
            format!(
                "names {} axes but {} has {} (shape {shape:?})",
                axes.len(),
                data_path.display(),
                shape.len()
            ),
        ));
    }
    let n_angles = acquisition.sequence.n_angles();
    let n_elements = acquisition.probe.n_elements;
    let canonical: Vec<usize> = perm.iter().map(|&i| shape[i]).collect();
    let (events, channels, samples) = match canonical.as_slice() {
        [f, a, c, s] => {
            if *a != n_angles {
                let axis = axes.get(perm[1]).map_or("angles", String::as_str);
                return Err(IoError::invalid(
                    path,
                    "[acquisition].angles",
                    format!(
                        "lists {n_angles} angles (so {n_angles} events per compound frame) but \
                         the '{axis}' axis of {} has {a} (shape {shape:?})",
                        data_path.display()
                    ),
                ));
            }
            (f.checked_mul(*a).unwrap_or(usize::MAX), *c, *s)
        }
        [e, c, s] => (*e, *c, *s),
        _ => {
            return Err(IoError::invalid(
                path,
                "[data].axes",
                "must name 3 or 4 axes",
            ));
        }
    };
    if channels != n_elements {
        return Err(IoError::invalid(
            path,
            "[probe].n_elements",
            format!(
                "is {n_elements} but the 'channels' axis of {} has {channels} (shape {shape:?})",
                data_path.display()
            ),
        ));
    }
    Ok((events, channels, samples))
}

/// The named axes of samples in canonical order: (frames, angles, channels, samples) in a version 1
/// manifest, (frames, events, channels, samples) from version 2 (the second axis counts the events
/// of a compound frame: a coded event fires every angle), or (events, channels, samples).
pub(super) fn canonical_axes(count: usize, version: i64) -> &'static [&'static str] {
    match (count, version) {
        (4, 1) => &["frames", "angles", "channels", "samples"],
        (4, _) => &["frames", "events", "channels", "samples"],
        _ => &["events", "channels", "samples"],
    }
}

/// For each canonical axis ([`canonical_axes`]), its index among the named axes.
pub(super) fn axis_permutation(axes: &[String], version: i64) -> Result<Vec<usize>, String> {
    let canonical = canonical_axes(axes.len(), version);
    let is_perm = (axes.len() == 3 || axes.len() == 4)
        && canonical
            .iter()
            .all(|c| axes.iter().filter(|a| a.as_str() == *c).count() == 1);
    if !is_perm {
        let four = canonical_axes(4, version);
        let hint = if version >= 2 && axes.iter().any(|a| a == "angles") {
            " (from version 2 the axis of the events of a compound frame is named \"events\", \
             not \"angles\": a coded event fires every angle)"
        } else {
            ""
        };
        return Err(format!(
            "is {axes:?}; expected an ordering of {four:?} or of [\"events\", \"channels\", \
             \"samples\"]{hint}"
        ));
    }
    Ok(canonical
        .iter()
        .map(|c| axes.iter().position(|a| a == c).unwrap_or(0))
        .collect())
}

/// Permutes named axes into canonical order and merges (frames, angles) into events.
pub(super) fn to_events<T: Clone>(
    a: ArrayD<T>,
    perm: &[usize],
    shape: (usize, usize, usize),
) -> Result<Array3<T>, ndarray::ShapeError> {
    // Samples already in canonical order (what pcuvd writes) are only reshaped, not copied: a
    // copy would double the memory a long recording takes while it is read.
    if perm.iter().enumerate().all(|(i, &p)| i == p) && a.is_standard_layout() {
        return a.into_shape_with_order(shape);
    }
    let p = a.permuted_axes(perm.to_vec());
    let values: Vec<T> = p.iter().cloned().collect();
    Array3::from_shape_vec(shape, values)
}
