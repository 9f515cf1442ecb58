//! `kincal certificate RUN`: the calibration certificate of a RUN, as an HTML page.

use anyhow::Result;
use clap::Args;
use std::path::PathBuf;

#[derive(Args)]
pub struct CertificateArgs {
    /// A RUN folder written by `kincal calibrate`.
    run: PathBuf,
    /// Who issues the certificate (printed on it).
    #[arg(long)]
    operator: Option<String>,
    /// Where to write the page (default RUN/certificate.html); an existing file is replaced only
    /// when it is a certificate kincal wrote.
    #[arg(long)]
    out: Option<PathBuf>,
}

/// Exit status when no calibration can be certified (the page is written and says why).
pub const NOT_CERTIFIED: i32 = 2;

pub fn cmd_certificate(a: &CertificateArgs) -> Result<()> {
    let now = kincal::controller::traceability::unix_now();
    let certificate = kincal::api::certificate(&a.run, a.operator.as_deref(), now)?;
    let path = kincal::store::certificate::write_certificate(&certificate, a.out.as_deref())?;
    let verdict = certificate.verdict();
    println!("{}: {}", verdict.headline, verdict.sentence);
    println!("RUN sha256:{}", certificate.run_sha256);
    println!("certificate written to {}", path.display());
    println!("next: {}", certificate.next_command());
    if verdict.class == "fail" {
        eprintln!("error: no calibration can be certified: {}", verdict.headline.to_lowercase());
        std::process::exit(NOT_CERTIFIED);
    }
    Ok(())
}
