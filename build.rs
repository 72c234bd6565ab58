//! Rebuild when a file of `viewer/` changes, is added or removed: `strata serve` embeds the folder,
//! and the compiler alone only notices changes to files it already embedded.

fn main() {
    println!("cargo:rerun-if-changed=viewer");
}
