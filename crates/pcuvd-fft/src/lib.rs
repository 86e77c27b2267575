//! FFT plans for pcuvd, in single (`f32`) and double (`f64`) precision, made by rustfft's planner.
//!
//! rustfft's planner is generic over the float type, so every crate that calls
//! `FftPlanner::<T>::new()` compiles every FFT algorithm rustfft builds (butterflies, radix,
//! Bluestein, each in scalar and AVX; the workspace leaves rustfft's SSE plans out) for that type:
//! 42 % of the pcuvd crate's LLVM IR, compiled again for its unit tests. The planners here are
//! concrete types, compiled once in this crate; their plans are trait objects, so a caller only
//! calls through a vtable and compiles none of the algorithms.

use std::sync::Arc;

pub use rustfft::Fft;

macro_rules! planner {
    ($name:ident, $float:ty, $what:literal) => {
        #[doc = concat!("An FFT planner for ", $what, " complex samples: plans of one length are made once and shared.")]
        pub struct $name(rustfft::FftPlanner<$float>);

        impl $name {
            /// A planner that uses AVX (x86-64) or NEON (ARM) plans where the CPU has them, scalar
            /// ones otherwise.
            pub fn new() -> Self {
                Self(rustfft::FftPlanner::new())
            }

            /// The forward transform of `len` samples (unnormalised: X[k] = Σ x[n] e^(−2πikn/len)).
            pub fn plan_fft_forward(&mut self, len: usize) -> Arc<dyn Fft<$float>> {
                self.0.plan_fft_forward(len)
            }

            /// The inverse transform of `len` samples (unnormalised: the sum has e^(+2πikn/len), no 1/len).
            pub fn plan_fft_inverse(&mut self, len: usize) -> Arc<dyn Fft<$float>> {
                self.0.plan_fft_inverse(len)
            }
        }

        impl Default for $name {
            fn default() -> Self {
                Self::new()
            }
        }
    };
}

planner!(FftPlanner32, f32, "single-precision (`f32`)");
planner!(FftPlanner64, f64, "double-precision (`f64`)");
