//! Puts the selected board's memory map where cortex-m-rt's `link.x` looks for `memory.x`.
use std::path::PathBuf;

fn main() {
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("OUT_DIR"));
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("manifest dir"));
    let memory = if std::env::var_os("CARGO_FEATURE_BOARD_MPS2").is_some() {
        manifest.join("boards/mps2/memory.x")
    } else if std::env::var_os("CARGO_FEATURE_BOARD_STM32").is_some() {
        manifest.join("../memory.x")
    } else {
        return;
    };
    std::fs::copy(&memory, out.join("memory.x")).expect("copy memory.x");
    println!("cargo:rerun-if-changed={}", memory.display());
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    if std::env::var_os("CARGO_FEATURE_BOARD_STM32").is_some() {
        // defmt's symbol table (logging over RTT).
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    }
}
