//! Links the `pipeline` executable as a position-dependent (non-PIE) executable on Linux.
//!
//! A PIE of this size carries about 38,000 relative relocations that the dynamic loader
//! applies at every start, copying some 140 pages of relocated data; a fixed-address
//! executable has none, which takes about 0.4 ms off every command (docs/benchmarks.md,
//! map import). The price is that the executable's own code is not placed at a random
//! address (its libraries, stack and heap still are). Only the binaries are linked so;
//! the crates are compiled as usual.
fn main() {
    let os = std::env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    let env = std::env::var("CARGO_CFG_TARGET_ENV").unwrap_or_default();
    if os == "linux" && env == "gnu" {
        println!("cargo:rustc-link-arg-bins=-no-pie");
    }
}
