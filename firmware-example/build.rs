//! Puts `memory.x` on the linker path and adds defmt's linker script when defmt logs.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::copy("memory.x", out.join("memory.x")).expect("memory.x is readable");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");
    let defmt = env::var_os("CARGO_FEATURE_DEFMT").is_some();
    let plain = env::var_os("CARGO_FEATURE_PLAIN").is_some();
    if defmt && !plain {
        println!("cargo:rustc-link-arg=-Tdefmt.x");
    }
}
