//! Bytes as a chunk file whose checksums and file size are recomputed first
//! (`strata::fuzzing::reseal`), so that mutations reach the decoding behind them; then everything
//! the `reader` target does.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = strata::fuzzing::read_everything_resealed(data);
});
