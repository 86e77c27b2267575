//! Which pixels of a recording are vessels for the RI maps: the whole-recording power tests.

pub use crate::estimate::masks::{
    VESSEL_LOCAL_DB, VESSEL_LOCAL_RADIUS_M, VESSEL_MARGIN_DB, VesselTests,
};
