//! Vessel class codes, shared by the phantoms' ground truth and the dynamics stage's maps (as
//! stored in `vessel_class.npy`).

/// Class code of a pixel outside every vessel.
pub const BACKGROUND: u8 = 0;
/// Class code of an arteriole (high RI).
pub const ARTERIOLE: u8 = 1;
/// Class code of a venule (low RI).
pub const VENULE: u8 = 2;
/// Class code of a vessel pixel whose RI lies between the arteriole and venule thresholds.
pub const UNDETERMINED: u8 = 3;
/// Class code of a capillary in a phantom's ground truth: an anatomical class, not one of the
/// dynamics stage's verdicts (which never gives it).
pub const CAPILLARY: u8 = 4;
