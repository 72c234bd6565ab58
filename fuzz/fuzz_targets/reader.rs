//! Bytes as a chunk file: open, every node decoded, every level assembled, verify, inspect.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = strata::fuzzing::read_everything(data);
});
