//! ply writer.
