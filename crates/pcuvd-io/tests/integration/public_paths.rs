//! Every path pcuvd-io offered before its readers moved into `readers/` (and its shared
//! vocabulary into `recording`) still resolves: this file compiles, or the public API broke.

#![allow(unused_imports)]

use pcuvd_io::array::{
    ArrayFrames, Axis, Backing, Block, Dtype, MAX_FRAME_BYTES, StoredArray, check_frame_size,
};
use pcuvd_io::cardiac::read_trigger_times;
use pcuvd_io::datafile::{DataSpec, open_data_array, open_hdf5_array, parse_data_file, read_whole};
use pcuvd_io::error::IoError;
use pcuvd_io::frames::ManifestFrames;
use pcuvd_io::hdf5::{
    H5Kind, Hdf5, MAX_PARAMETER_ELEMENTS, element_count, guard, kind_of, read_slice_f64,
};
use pcuvd_io::layout::{common_t0, crossing_time, linear_array, per_transmit, positive, scalar};
use pcuvd_io::manifest::{
    FORMAT, Recording, RecordingWriter, VERSION, read_manifest, read_recording, write_recording,
};
use pcuvd_io::mat::{MatFile, MatValue, NumericClass, read_mat, write_mat};
use pcuvd_io::mat73::{class_of, read_value};
use pcuvd_io::must::{
    DEFAULT_BANDWIDTH_PERCENT, DEFAULT_PULSE_CYCLES, DEFAULT_SOUND_SPEED, from_mat, open_npz,
    open_v5, open_v73, plane_wave_angle, read_must_mat,
};
use pcuvd_io::npy::{
    NpyArray, read_npy, remove_partial_files, write_atomically, write_json, write_npy,
};
use pcuvd_io::npz::{npz_members, open_npy, open_npz_member, read_npz_values};
use pcuvd_io::open::{
    Container, FORMATS, OpenedRecording, SourceInfo, StoredSamples, open_recording, read_head,
    sniff,
};
use pcuvd_io::params::{
    Overrides, ParamSource, Parameter, Resolver, derived, field, missing_prf, missing_t0,
};
use pcuvd_io::paths::{check_regular_file, what_is};
use pcuvd_io::uff::DEFAULT_BANDWIDTH;
use pcuvd_io::verasonics::VerasonicsFrames;
use pcuvd_io::zea::{frame_timing, transmit_polarity};

/// The crate root's re-exports.
mod root {
    use pcuvd_io::{
        IoError, ManifestFrames, MatFile, MatValue, NumericClass, OpenedRecording, Overrides,
        ParamSource, Parameter, Recording, RecordingWriter, SourceInfo, StoredSamples,
        check_regular_file, open_recording, read_manifest, read_mat, read_must_mat, read_recording,
        read_trigger_times, remove_partial_files, write_atomically, write_json, write_mat,
        write_npy, write_recording,
    };
    use pcuvd_io::{
        uff::open as open_uff, verasonics::open as open_verasonics, zea::open as open_zea,
    };
}

#[test]
fn the_shared_defaults_are_one_value_wherever_they_are_named() {
    assert_eq!(
        pcuvd_io::must::DEFAULT_PULSE_CYCLES,
        pcuvd_io::recording::DEFAULT_PULSE_CYCLES
    );
    assert_eq!(
        pcuvd_io::uff::DEFAULT_BANDWIDTH,
        pcuvd_io::recording::DEFAULT_BANDWIDTH
    );
}
