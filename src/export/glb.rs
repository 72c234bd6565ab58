//! glb writer.
