//! `kincal igtl-record`: the TRANSFORMs an OpenIGTLink server sends, recorded as a client
//! receives them, for `kincal dynamic`.

use crate::controller::{catch_ctrl_c, igtl_address, INTERRUPTED};
use anyhow::{bail, Context, Result};
use clap::Args;
use kincal::controller::igtl_client::Recorder;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// `kincal igtl-record`.
#[derive(Args)]
pub struct IgtlRecordArgs {
    /// The server: [HOST:]PORT (a port alone means localhost), e.g. `kincal stream --igtl` or
    /// PLUS serving an optical tracker.
    #[arg(long, value_parser = igtl_address, value_name = "[HOST:]PORT")]
    connect: String,
    /// The transform to record, by its name (PLUS's FromToTo convention).
    #[arg(long, default_value = kincal::controller::igtl_server::DEFAULT_NAME)]
    name: String,
    /// The CSV to write (`t_s,x_mm,y_mm,z_mm,host_s`: the transform's timestamp, its translation
    /// and its arrival on this host); a new file.
    #[arg(long)]
    csv: PathBuf,
    /// Stop after this many seconds (default: when the server closes the connection, or Ctrl-C).
    #[arg(long, value_parser = positive_seconds)]
    seconds: Option<f64>,
}

/// `--seconds`: a positive number of seconds.
fn positive_seconds(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("expected a positive number of seconds (e.g. 30), found `{text}`")),
    }
}

pub fn cmd_igtl_record(a: &IgtlRecordArgs) -> Result<()> {
    if a.csv.exists() {
        bail!("{} exists; kincal never replaces a file with a recording: choose a new name", a.csv.display());
    }
    if !kincal::igtl::valid_name(&a.name) {
        bail!("--name `{}`: a transform name is 1 to 20 printable ASCII characters without spaces", a.name);
    }
    let addr = std::net::ToSocketAddrs::to_socket_addrs(&a.connect)?
        .next()
        .with_context(|| format!("--connect {}: no address", a.connect))?;
    let recorder = Recorder::connect(addr, &a.name, true).with_context(|| format!("connecting to {addr}"))?;
    println!("recording TRANSFORM {} from {addr} into {}", a.name, a.csv.display());
    catch_ctrl_c();
    let started = Instant::now();
    while recorder.is_open()
        && !INTERRUPTED.load(Ordering::SeqCst)
        && a.seconds.is_none_or(|s| started.elapsed().as_secs_f64() < s)
    {
        std::thread::sleep(Duration::from_millis(20));
    }
    let got = recorder.finish()?;
    kincal::files::write_atomic(&a.csv, kincal::motion::recording::track_csv(&got.track).as_bytes())
        .with_context(|| format!("writing {}", a.csv.display()))?;
    println!(
        "{} poses in {:.1} s written to {}; {} TRANSFORMs received ({} invalid, {} with a time not after the previous one: not written), {} STATUS messages{}",
        got.track.len(),
        started.elapsed().as_secs_f64(),
        a.csv.display(),
        got.transforms,
        got.invalid,
        got.unordered,
        got.status,
        if got.bad_crc > 0 { format!(", {} with a bad CRC (not used)", got.bad_crc) } else { String::new() }
    );
    if got.track.is_empty() {
        bail!("no TRANSFORM named {} arrived: is it the name the server sends?", a.name);
    }
    Ok(())
}
