//! Array memory reused from one block of frames to the next, complex samples seen as their
//! floats, a test that a block's floats are all finite, and a 1-D view seen as a slice.

use bytemuck::Zeroable;
use ndarray::{Array, ArrayView1, Dimension, IntoDimension};
use num_complex::Complex32;
use rayon::prelude::*;

/// An array of `shape` in `old`'s memory where that has room for it, else a new one: blocks of
/// frames come one after another in sizes that differ a little (a recording's first and last),
/// and fresh pages cost more to fault in and zero than the work done on them. The elements'
/// values are unspecified (the old array's or zeros): callers write every one.
pub fn array_reusing<T, D>(
    old: Option<Array<T, D>>,
    shape: impl IntoDimension<Dim = D>,
) -> Array<T, D>
where
    T: Clone + Zeroable + Send,
    D: Dimension,
{
    let shape = shape.into_dimension();
    let len = shape.size();
    let memory = old
        .map(|array| array.into_raw_vec_and_offset().0)
        .filter(|memory| memory.capacity() >= len);
    // (Memory too small is dropped by now, before the new array is allocated.)
    let memory = match memory {
        Some(mut memory) => {
            resize_zeroed(&mut memory, len);
            memory
        }
        // Zeroed by the allocator: pages the system maps in zeroed on first touch, by the
        // threads that first write them, rather than filled here on one.
        None => bytemuck::zeroed_vec(len),
    };
    Array::from_shape_vec(shape, memory).expect("exactly the shape's number of elements")
}

/// `memory` cut or lengthened to `len` elements, the new ones zero, written on every core: the
/// first block of a recording reserves room for the largest, and the pages of that room are
/// faulted in here.
fn resize_zeroed<T: Zeroable + Send>(memory: &mut Vec<T>, len: usize) {
    let old = memory.len();
    if len <= old {
        memory.truncate(len);
        return;
    }
    memory.spare_capacity_mut()[..len - old]
        .par_chunks_mut(1 << 16)
        .for_each(|chunk| {
            for v in chunk {
                v.write(T::zeroed());
            }
        });
    // SAFETY: the slice above reached `len` within the capacity (it panics short of it), and
    // every element from `old` to `len` was written.
    unsafe { memory.set_len(len) }
}

/// Complex samples as their floats, (re, im) after each other.
pub fn complex_floats(samples: &[Complex32]) -> &[f32] {
    // SAFETY: `Complex<f32>` is `#[repr(C)]` { re, im }: two f32 each, no padding.
    unsafe { std::slice::from_raw_parts(samples.as_ptr().cast(), 2 * samples.len()) }
}

/// [`complex_floats`], writable.
pub fn complex_floats_mut(samples: &mut [Complex32]) -> &mut [f32] {
    // SAFETY: as in `complex_floats`; the borrow is unique.
    unsafe { std::slice::from_raw_parts_mut(samples.as_mut_ptr().cast(), 2 * samples.len()) }
}

/// Whether every value is finite (no NaN or ±Inf), on one core. A float is not finite when its
/// exponent bits are all set; counting such values has no early exit, so the loop vectorises,
/// where `iter().all(is_finite)` tests one value at a time (a 2.8 GB recording took about
/// 1.5 s of CPU to scan that way).
pub fn floats_finite(values: &[f32]) -> bool {
    const EXPONENT: u32 = 0x7f80_0000;
    values
        .iter()
        .map(|v| u32::from(v.to_bits() & EXPONENT == EXPONENT))
        .sum::<u32>()
        == 0
}

/// [`floats_finite`] on every core, for a block of a recording.
pub fn floats_finite_on_every_core(values: &[f32]) -> bool {
    values.par_chunks(1 << 16).all(floats_finite)
}

/// A 1-D view's elements as a slice: borrowed where they lie contiguous (a pixel's frames in a
/// formed series, a trace of a recording), else copied.
pub fn contiguous<T: Clone>(view: ArrayView1<'_, T>) -> std::borrow::Cow<'_, [T]> {
    match view.to_slice() {
        Some(slice) => std::borrow::Cow::Borrowed(slice),
        None => std::borrow::Cow::Owned(view.to_vec()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An array takes the old one's memory where it has room (shorter, then as long again),
    /// and new memory where it has not; either way it has the asked-for shape, in standard
    /// layout.
    #[test]
    fn arrays_reuse_memory_with_room() {
        let old = ndarray::Array3::<f32>::from_elem((4, 3, 5), 1.5);
        let memory = old.as_ptr();
        let shorter = array_reusing(Some(old), (2, 3, 5));
        assert_eq!(shorter.dim(), (2, 3, 5));
        assert_eq!(shorter.as_ptr(), memory);
        let again = array_reusing(Some(shorter), (4, 3, 5));
        assert_eq!(again.as_ptr(), memory);
        assert!(again.is_standard_layout());
        let longer = array_reusing(Some(again), (5, 3, 5));
        assert_eq!(longer.dim(), (5, 3, 5));
        assert!(longer.is_standard_layout());
        let fresh = array_reusing::<f32, _>(None, (1, 2, 3));
        assert!(fresh.iter().all(|&v| v == 0.0));
    }

    /// Finite extremes (largest, smallest normal, subnormal, signed zeros) pass; a NaN (quiet
    /// or signalling, either sign) or an infinity anywhere fails, in the first, a middle or
    /// the last of several parallel chunks, as `f32::is_finite` says of each.
    #[test]
    fn floats_are_finite_unless_one_is_nan_or_infinite() {
        let n = 3 * (1 << 16) + 17;
        let mut values: Vec<f32> = (0..n).map(|i| (i as f32 - 9e4) * 1e33).collect();
        let extremes = [
            f32::MAX,
            f32::MIN,
            f32::MIN_POSITIVE,
            1e-45,
            -1e-45,
            0.0,
            -0.0,
        ];
        values[..extremes.len()].copy_from_slice(&extremes);
        assert!(values.iter().all(|v| v.is_finite()));
        assert!(floats_finite(&values) && floats_finite_on_every_core(&values));
        assert!(floats_finite(&[]) && floats_finite_on_every_core(&[]));
        let bad = [
            f32::NAN,
            -f32::NAN,
            f32::from_bits(0x7f80_0001),
            f32::INFINITY,
            f32::NEG_INFINITY,
        ];
        for (k, &v) in bad.iter().enumerate() {
            for at in [0, 1 << 16, n / 2 + k, n - 1] {
                let old = std::mem::replace(&mut values[at], v);
                assert!(!floats_finite(&values), "{v} at {at}");
                assert!(!floats_finite_on_every_core(&values), "{v} at {at}");
                values[at] = old;
            }
        }
        assert!(floats_finite(&values) && floats_finite_on_every_core(&values));
    }
}
