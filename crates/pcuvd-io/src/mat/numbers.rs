//! The values of a MATLAB numeric array as the file stores them: MATLAB saves a double array in
//! a smaller integer type when its values fit (a scanner's samples are int16), and those bytes
//! are kept, not widened to f64, until a reader converts a block of them.

use std::borrow::Cow;
use std::sync::Arc;

use crate::array::{Backing, Dtype, StoredArray};

/// The values of a numeric array, column-major: f64, or the bytes of the type the file stores.
#[derive(Debug, Clone)]
pub enum Numbers {
    /// Values as f64 (MATLAB's double storage, or built in memory).
    F64(Vec<f64>),
    /// Values as stored: `dtype` elements (8-, 16- or 32-bit integers or f32, each exact in f64)
    /// in `bytes`, little- or big-endian.
    Stored {
        /// The element type.
        dtype: Dtype,
        /// Little-endian elements.
        little: bool,
        /// The elements' bytes, `dtype.size()` each.
        bytes: Vec<u8>,
    },
}

impl Numbers {
    /// The number of values.
    pub fn len(&self) -> usize {
        match self {
            Numbers::F64(v) => v.len(),
            Numbers::Stored { dtype, bytes, .. } => bytes.len() / dtype.size(),
        }
    }

    /// True when there are no values.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value `i`, exact (every stored type fits in f64).
    pub fn get(&self, i: usize) -> Option<f64> {
        match self {
            Numbers::F64(v) => v.get(i).copied(),
            Numbers::Stored {
                dtype,
                little,
                bytes,
            } => {
                let size = dtype.size();
                bytes
                    .get(i * size..(i + 1) * size)
                    .map(|b| dtype.decode_f64(b, *little))
            }
        }
    }

    /// The values as f64, borrowed when they already are.
    pub fn to_f64(&self) -> Cow<'_, [f64]> {
        match self {
            Numbers::F64(v) => Cow::Borrowed(v),
            Numbers::Stored { .. } => {
                Cow::Owned((0..self.len()).filter_map(|i| self.get(i)).collect())
            }
        }
    }

    /// The values as f64, converted in place when stored otherwise, for editing.
    pub fn as_f64_mut(&mut self) -> &mut Vec<f64> {
        if let Numbers::Stored { .. } = self {
            *self = Numbers::F64(self.to_f64().into_owned());
        }
        match self {
            Numbers::F64(v) => v,
            Numbers::Stored { .. } => unreachable!("converted to f64 above"),
        }
    }

    /// The values as an owned f64 vector.
    pub fn into_f64(self) -> Vec<f64> {
        match self {
            Numbers::F64(v) => v,
            stored => stored.to_f64().into_owned(),
        }
    }
}

impl From<Vec<f64>> for Numbers {
    fn from(values: Vec<f64>) -> Self {
        Numbers::F64(values)
    }
}

impl FromIterator<f64> for Numbers {
    fn from_iter<I: IntoIterator<Item = f64>>(values: I) -> Self {
        Numbers::F64(values.into_iter().collect())
    }
}

/// Equal when the values are (as f64: NaN equals nothing), however each side stores them.
impl PartialEq for Numbers {
    fn eq(&self, other: &Self) -> bool {
        self.len() == other.len() && self.to_f64() == other.to_f64()
    }
}

/// A MATLAB variable's samples as a [`StoredArray`] (MATLAB dimensions, column-major): stored
/// bytes stay in their type until a block is read; complex values (two arrays) as f64.
pub fn stored_array(
    dims: Vec<usize>,
    real: Numbers,
    imag: Option<Numbers>,
    label: String,
) -> StoredArray {
    let (dtype, backing) = match (real, imag) {
        (
            Numbers::Stored {
                dtype,
                little,
                bytes,
            },
            None,
        ) => (
            dtype,
            Backing::Bytes {
                bytes: Arc::new(bytes),
                little,
            },
        ),
        (real, imag) => (
            Dtype::F64,
            Backing::Values {
                real: Arc::new(real.into_f64()),
                imag: imag.map(|i| Arc::new(i.into_f64())),
            },
        ),
    };
    StoredArray {
        shape: dims,
        dtype,
        fortran: true,
        backing,
        label,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stored_values_read_exactly_and_equal_the_same_values_as_f64() {
        let values = [-32768.0, -1.0, 0.0, 7.0, 32767.0];
        for little in [true, false] {
            let bytes: Vec<u8> = values
                .iter()
                .flat_map(|&v| {
                    let v = v as i16;
                    if little {
                        v.to_le_bytes()
                    } else {
                        v.to_be_bytes()
                    }
                })
                .collect();
            let mut stored = Numbers::Stored {
                dtype: Dtype::I16,
                little,
                bytes,
            };
            assert_eq!(stored.len(), 5);
            assert_eq!(stored.get(4), Some(32767.0));
            assert_eq!(stored.get(5), None);
            assert_eq!(&*stored.to_f64(), &values[..]);
            assert_eq!(stored, Numbers::from(values.to_vec()));
            assert_ne!(stored, Numbers::from(values[..4].to_vec()));
            stored.as_f64_mut()[0] = 1.5;
            assert_eq!(stored.get(0), Some(1.5));
        }
    }

    #[test]
    fn samples_stored_narrow_stay_bytes_and_complex_ones_decode() {
        let real = Numbers::Stored {
            dtype: Dtype::I16,
            little: true,
            bytes: vec![1, 0, 2, 0],
        };
        let a = stored_array(vec![2, 1], real.clone(), None, "rf".into());
        assert_eq!(a.dtype, Dtype::I16);
        assert_eq!(a.resident_bytes(), 4);
        let c = stored_array(vec![2, 1], real, Some(vec![3.0, 4.0].into()), "iq".into());
        assert!(c.is_complex());
        assert_eq!(c.resident_bytes(), 32);
    }
}
