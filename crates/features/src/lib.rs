//! stillpoint-features: see the crate's issue; filled in by its owner.
