//! Quadric-error edge collapse, optionally keeping every group of a face partition a connected,
//! non-empty patch.
