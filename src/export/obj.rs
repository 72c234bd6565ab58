//! obj writer.
