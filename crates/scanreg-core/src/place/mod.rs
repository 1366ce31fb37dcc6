//! Place recognition: a global descriptor per scan and retrieval of the scans that look like
//! the same place, for loop-closure candidates when the pose graph's guess is too far off for
//! local registration.
//!
//! Scan Context (Kim & Kim, IROS 2018): the cloud around the sensor, split into `rings × sectors`
//! polar bins in the xy plane, each holding the highest point's height ([`scan_context`]); two
//! descriptors compared under every column shift, which also gives the yaw between them
//! ([`distance`]); a database that shortlists by the rotation-invariant ring key and ranks
//! the shortlist by the full distance ([`database`]).

pub mod database;
pub mod distance;
pub mod scan_context;

pub use database::{PlaceMatch, ScanContextDatabase};
pub use distance::{checked_scan_context_distance, scan_context_distance, ShiftMatch};
pub use scan_context::{ring_key, scan_context, ScanContextParams};
