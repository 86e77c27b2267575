//! Array memory reused from one block of frames to the next (rows padded to whole cache lines
//! where a kernel reads them as vectors), complex samples seen as their floats, a test that a
//! block's floats are all finite, and a 1-D view seen as a slice.
//!
//! New memory is left in the system's ordinary pages, not advised into transparent huge pages:
//! in a virtual machine whose balloon reports free pages to its host, every huge page a new
//! process faults in comes back from the host unbacked and is cleared at about 0.4 GB/s, against
//! 1.3–1.9 GB/s for the same memory in 4 KiB pages (the 2.2 GB of a 360-frame coded recording's
//! images: about 5 s of system time against 2.5).

use bytemuck::Zeroable;
use ndarray::{Array, Array1, Array3, ArrayView, ArrayView1, Dimension, IntoDimension, s};
use num_complex::Complex32;
use rayon::prelude::*;

use crate::core::error::{Result, invalid};

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
    let memory = memory_reusing(
        old.map(|array| array.into_raw_vec_and_offset().0),
        shape.size(),
    );
    Array::from_shape_vec(shape, memory).expect("exactly the shape's number of elements")
}

/// A copy of `values` in `old`'s memory where that has room for it ([`array_reusing`]), copied
/// on every core where `values` lie in one run of memory: a block of frames taken from a
/// recording held in memory is copied into the previous block's pages rather than fresh ones,
/// which cost more to fault in and zero than the copy.
pub fn copy_reusing<T, D>(values: ArrayView<'_, T, D>, old: Option<Array<T, D>>) -> Array<T, D>
where
    T: Copy + Zeroable + Send + Sync,
    D: Dimension,
{
    let mut copy = array_reusing(old, values.raw_dim());
    match (values.as_slice(), copy.as_slice_mut()) {
        (Some(from), Some(to)) => to
            .par_chunks_mut(1 << 16)
            .zip(from.par_chunks(1 << 16))
            .for_each(|(to, from)| to.copy_from_slice(from)),
        _ => copy.assign(&values),
    }
    copy
}

/// An array of zeros of `shape`, in `old`'s memory where that has room for it (zeroed here, on
/// every core), else in new memory: blocks of simulated traces, one after another, are made in
/// the memory of a block already written, whose pages are faulted in.
pub fn zeros_reusing<T, D>(
    old: Option<Array<T, D>>,
    shape: impl IntoDimension<Dim = D>,
) -> Array<T, D>
where
    T: Zeroable + Send,
    D: Dimension,
{
    let shape = shape.into_dimension();
    // Emptied, the old memory keeps its room and is zeroed whole where it is reused.
    let emptied = old.map(|array| {
        let mut memory = array.into_raw_vec_and_offset().0;
        memory.clear();
        memory
    });
    let memory = memory_reusing(emptied, shape.size());
    Array::from_shape_vec(shape, memory).expect("exactly the shape's number of elements")
}

/// `len` elements in `old` where it has room for them, else in new zeroed memory; the values
/// are unspecified.
fn memory_reusing<T: Zeroable + Send>(old: Option<Vec<T>>, len: usize) -> Vec<T> {
    // (Memory too small is dropped by now, before the new memory is allocated.)
    match old.filter(|memory| memory.capacity() >= len) {
        Some(mut memory) => {
            resize_zeroed(&mut memory, len);
            memory
        }
        // Zeroed by the allocator: pages the system maps in zeroed on first touch, by the
        // threads that first write them, rather than filled here on one.
        None => bytemuck::zeroed_vec(len),
    }
}

/// Refuses a request for `bytes` of memory that the system cannot map at all (beyond its
/// address space or its overcommit limit), with `what` needs them said in the message: asked
/// of the allocator later, such a request aborts the process. The probe maps nothing it keeps
/// and touches no page.
pub fn check_allocatable(bytes: u128, what: &str) -> Result<()> {
    let refused = || {
        invalid(
            "memory",
            format!(
                "{what} need {:.3e} bytes ({:.0} GB), more than this machine can allocate",
                bytes as f64,
                bytes as f64 / 1e9
            ),
        )
    };
    let len = usize::try_from(bytes).map_err(|_| refused())?;
    Vec::<u8>::new()
        .try_reserve_exact(len)
        .map_err(|_| refused())
}

/// Bytes of a cache line, to which [`padded_rows_reusing`] aligns every row.
pub const CACHE_LINE: usize = 64;

/// A (planes, rows, columns) array whose rows each start on a cache line: the memory holds rows
/// of `columns` padded to a whole number of cache lines, and the first element is aligned to one,
/// so that a kernel loading a row as 64-byte vectors never has a load split across two lines
/// (one split in every such load of a 90-frame row of complex samples, 720 bytes, otherwise).
/// Returned whole, padding included, (planes, rows, padded columns) in standard layout, for the
/// caller to write; `.slice_move(s![.., .., ..columns])` then gives the array of `columns`.
/// Made in `old`'s memory where that has room, as [`array_reusing`]; the values, padding
/// included, are unspecified.
pub fn padded_rows_reusing<T>(
    old: Option<Array3<T>>,
    (planes, rows, columns): (usize, usize, usize),
) -> Array3<T>
where
    T: Clone + Zeroable + Send,
{
    let size = std::mem::size_of::<T>().max(1);
    // Element types that do not tile a cache line are padded to nothing and not aligned.
    let per_line = if CACHE_LINE.is_multiple_of(size) {
        CACHE_LINE / size
    } else {
        1
    };
    let padded = columns.next_multiple_of(per_line);
    let len = planes * rows * padded;
    // Room to move the start forward to a line.
    let room = len + per_line - 1;
    let memory = memory_reusing(old.map(|array| array.into_raw_vec_and_offset().0), room);
    let misaligned = (memory.as_ptr() as usize % CACHE_LINE) / size;
    let offset =
        if per_line > 1 && misaligned > 0 && (memory.as_ptr() as usize).is_multiple_of(size) {
            per_line - misaligned
        } else {
            0
        };
    Array1::from_vec(memory)
        .slice_move(s![offset..offset + len])
        .into_shape_with_order((planes, rows, padded))
        .expect("a contiguous run of the shape's number of elements")
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

/// Whether every complex value of `array` has finite parts: [`floats_finite_on_every_core`] where
/// its elements are one run of memory (a recording's IQ block, a formed series), else a value at
/// a time.
pub fn complex_finite_on_every_core<D: Dimension>(array: ArrayView<'_, Complex32, D>) -> bool {
    match array.as_slice_memory_order() {
        Some(values) => floats_finite_on_every_core(complex_floats(values)),
        None => array.iter().all(|v| v.re.is_finite() && v.im.is_finite()),
    }
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

    /// A copy holds every value where it was, in the old array's memory where that has room,
    /// from a view in one run of memory (copied in chunks on every core) or strided.
    #[test]
    fn copies_hold_every_value_in_reused_memory() {
        let whole = ndarray::Array3::from_shape_fn((9, 3, 70_000), |(e, c, s)| {
            (e * 1_000_003 + c * 70_001 + s) as f32
        });
        let old = ndarray::Array3::<f32>::from_elem((5, 3, 70_000), -1.0);
        let memory = old.as_ptr();
        let block = whole.slice(s![2..6, .., ..]);
        let copy = copy_reusing(block, Some(old));
        assert_eq!(copy, block);
        assert_eq!(copy.as_ptr(), memory);
        let strided = whole.slice(s![.., 1.., ..;3]);
        let copy = copy_reusing(strided, None);
        assert_eq!(copy, strided);
        assert!(copy.is_standard_layout());
    }

    /// What no machine can allocate is refused with what needed it; a small request passes and
    /// keeps nothing.
    #[test]
    fn requests_beyond_any_machine_are_refused_by_name() {
        assert!(check_allocatable(1 << 20, "a megabyte").is_ok());
        for bytes in [u128::MAX, 1 << 62] {
            let refused = check_allocatable(bytes, "a billion frames").unwrap_err();
            let message = refused.to_string();
            assert!(message.contains("a billion frames need"), "{message}");
            assert!(
                message.contains("more than this machine can allocate"),
                "{message}"
            );
        }
    }

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

    /// Zeros in the old array's memory where it has room, whatever it held, and in new memory
    /// where it has not.
    #[test]
    fn zeros_reuse_memory_with_room_and_hold_nothing_of_it() {
        let old = ndarray::Array3::<f32>::from_elem((4, 3, 5), 1.5);
        let memory = old.as_ptr();
        let shorter = zeros_reusing(Some(old), (2, 3, 5));
        assert_eq!(shorter.as_ptr(), memory);
        assert!(shorter.iter().all(|&v| v == 0.0));
        let mut again = zeros_reusing(Some(shorter), (4, 3, 5));
        assert_eq!(again.as_ptr(), memory);
        assert!(again.iter().all(|&v| v == 0.0));
        again.fill(2.5);
        let longer = zeros_reusing(Some(again), (5, 3, 5));
        assert_eq!(longer.dim(), (5, 3, 5));
        assert!(longer.iter().all(|&v| v == 0.0));
    }

    /// Rows of complex samples are padded to whole cache lines and start on one, fresh or in
    /// reused memory (shorter, then longer than the memory holds); the logical array cut from
    /// it keeps the asked-for shape with the padded row stride.
    #[test]
    fn padded_rows_start_on_cache_lines() {
        let mut old = None;
        for (shape, padded) in [
            ((2, 3, 90), 96),
            ((1, 5, 8), 8),
            ((3, 2, 1), 8),
            ((4, 7, 97), 104),
        ] {
            let whole = padded_rows_reusing::<Complex32>(old.take(), shape);
            assert_eq!(whole.dim(), (shape.0, shape.1, padded), "{shape:?}");
            assert!(whole.is_standard_layout());
            let rows = whole.slice_move(s![.., .., ..shape.2]);
            assert_eq!(rows.dim(), shape);
            let first = rows.as_ptr() as usize;
            for plane in 0..shape.0 {
                for row in 0..shape.1 {
                    let at = &rows[[plane, row, 0]] as *const Complex32 as usize;
                    assert_eq!(at % CACHE_LINE, 0, "{shape:?}, row {plane}, {row}");
                    let rows_before = plane * shape.1 + row;
                    assert_eq!(at - first, rows_before * padded * 8, "{shape:?}");
                }
            }
            old = Some(rows);
        }
        // Elements that do not tile a line are left unpadded.
        let odd = padded_rows_reusing::<[u8; 3]>(None, (2, 2, 5));
        assert_eq!(odd.dim(), (2, 2, 5));
    }

    /// A complex array is finite unless a part of one value is NaN or infinite, whether its
    /// elements are one run of memory or strided.
    #[test]
    fn complex_arrays_are_finite_unless_one_part_is_not() {
        let mut array = ndarray::Array3::from_shape_fn((3, 4, 70_000), |(a, b, c)| {
            Complex32::new((a + b) as f32, c as f32 * -1e30)
        });
        let strided = |a: &ndarray::Array3<Complex32>| {
            complex_finite_on_every_core(a.slice(s![.., .., ..;3]))
        };
        assert!(complex_finite_on_every_core(array.view()) && strided(&array));
        for bad in [
            Complex32::new(f32::NAN, 0.0),
            Complex32::new(0.0, f32::INFINITY),
        ] {
            let old = std::mem::replace(&mut array[[2, 1, 69_999]], bad);
            assert!(!complex_finite_on_every_core(array.view()), "{bad}");
            assert!(
                !complex_finite_on_every_core(array.view().reversed_axes()),
                "{bad}"
            );
            array[[2, 1, 69_999]] = old;
            let old = std::mem::replace(&mut array[[1, 3, 3]], bad);
            assert!(!strided(&array), "{bad}");
            array[[1, 3, 3]] = old;
        }
        assert!(complex_finite_on_every_core(array.view()) && strided(&array));
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
