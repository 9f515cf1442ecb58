//! Puts the selected board's memory map where cortex-m-rt's `link.x` looks for `memory.x`, and
//! writes the build-time provisioning (`KINCAL_TRUSTED_KEY`, `KINCAL_ARM_ID`) for `src/trust.rs`.
use std::path::{Path, PathBuf};

/// `BUILD_KEY` and `BUILD_ARM_ID` from the environment; a malformed value stops the build.
fn provisioning(out: &Path) {
    println!("cargo:rerun-if-env-changed=KINCAL_TRUSTED_KEY");
    println!("cargo:rerun-if-env-changed=KINCAL_ARM_ID");
    let key = match std::env::var("KINCAL_TRUSTED_KEY") {
        Ok(hex) => {
            let hex = hex.trim();
            let bytes: Option<Vec<u8>> = (hex.len() == 64)
                .then(|| (0..32).map(|k| u8::from_str_radix(hex.get(2 * k..2 * k + 2)?, 16).ok()).collect())
                .flatten();
            let Some(bytes) = bytes else {
                panic!("KINCAL_TRUSTED_KEY must be the station's public key, 64 hex digits (`kincal key new` prints it), not {hex:?}")
            };
            format!("Some({bytes:?})")
        }
        Err(_) => "None".into(),
    };
    let arm = match std::env::var("KINCAL_ARM_ID") {
        Ok(id) => {
            let valid = (1..=24).contains(&id.len())
                && id.bytes().all(|b| b.is_ascii_alphanumeric() || b"-_.:".contains(&b));
            assert!(valid, "KINCAL_ARM_ID must be 1 to 24 ASCII letters, digits or -_.: (not {id:?})");
            format!("Some({id:?})")
        }
        Err(_) => "None".into(),
    };
    let code = format!(
        "/// Public key built into the firmware (`KINCAL_TRUSTED_KEY`); `None`: trust on first use.\n\
         pub const BUILD_KEY: Option<[u8; 32]> = {key};\n\
         /// Arm identity built into the firmware (`KINCAL_ARM_ID`); `None`: the board's own.\n\
         pub const BUILD_ARM_ID: Option<&str> = {arm};\n"
    );
    std::fs::write(out.join("provisioning.rs"), code).expect("write provisioning.rs");
}

fn main() {
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("OUT_DIR"));
    provisioning(&out);
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
