//! Value parsers for options: a number outside its range (NaN, ∞, negative, absurd) is refused
//! by the argument parser with the range, before anything runs, and so is an unknown effect,
//! parameter or drift kind; and the built-in model that `--model` defaults to.

use kincal::model::effects::Effect;
use kincal::model::ParamId;
use std::path::{Path, PathBuf};

/// The SUTA model built into kincal, as a file for the length of one command: `simulate` reads
/// `--model` from a path, and when the option is left out it reads this file, so it runs from
/// any folder. The file is removed when the command ends.
pub struct BuiltinModelFile(PathBuf);

impl BuiltinModelFile {
    /// Write the built-in model to a new file in the temporary folder.
    pub fn write() -> std::io::Result<BuiltinModelFile> {
        use std::io::Write;
        let name = format!("kincal-suta-model-{}.toml", std::process::id());
        let path = std::env::temp_dir().join(name);
        let mut file = std::fs::OpenOptions::new().write(true).create_new(true).open(&path)?;
        file.write_all(kincal::model::file::SUTA_MODEL_TOML.as_bytes())?;
        Ok(BuiltinModelFile(path))
    }

    /// Where the file is.
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for BuiltinModelFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// A finite real number in `[min, max]`, in `unit`.
pub fn real(min: f64, max: f64, unit: &'static str) -> impl Fn(&str) -> Result<f64, String> + Clone {
    move |text: &str| {
        let value: f64 = text.trim().parse().map_err(|_| format!("expected a number, found `{text}`"))?;
        if value.is_finite() && (min..=max).contains(&value) {
            Ok(value)
        } else {
            Err(format!("expected a number from {min} to {max} {unit}, found {text}"))
        }
    }
}

/// A whole number in `[min, max]`.
pub fn count(min: usize, max: usize) -> impl Fn(&str) -> Result<usize, String> + Clone {
    move |text: &str| {
        let value: usize =
            text.trim().parse().map_err(|_| format!("expected a whole number, found `{text}`"))?;
        if (min..=max).contains(&value) {
            Ok(value)
        } else {
            Err(format!("expected a whole number from {min} to {max}, found {value}"))
        }
    }
}

/// `--add EFFECT`.
pub fn parse_effect(text: &str) -> Result<Effect, String> {
    Effect::parse(text).ok_or_else(|| {
        format!(
            "unknown effect `{text}`; expected one of {} (J: a joint number, N: 1–4 per revolution)",
            Effect::syntax()
        )
    })
}

/// `--drift-session SESSION[:KIND]`.
pub fn parse_drift(text: &str) -> Result<kincal::calib::nuisance::drift::DriftSpec, String> {
    text.parse()
}

/// `--hidden PARAM=DELTA`.
pub fn parse_hidden(text: &str) -> Result<(ParamId, f64), String> {
    let (name, value) = text.split_once('=').ok_or("expected PARAM=DELTA, e.g. eccentricity_sin:5=0.3")?;
    let id = ParamId::parse(name.trim()).ok_or_else(|| format!("unknown parameter `{name}`"))?;
    let delta: f64 = value.trim().parse().map_err(|_| format!("`{value}` is not a number"))?;
    let limit = kincal::model::plausible::plausible_limit(id);
    if !(delta.is_finite() && delta.abs() <= limit) {
        return Err(format!("`{value}`: expected a finite change of at most {limit} {}", id.unit()));
    }
    Ok((id, delta))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_outside_their_range_are_refused() {
        let delta = real(0.001, 1000.0, "mm");
        for bad in ["NaN", "inf", "-1", "0", "1e-300", "x", ""] {
            assert!(delta(bad).is_err(), "{bad}");
        }
        assert_eq!(delta("1.35"), Ok(1.35));
        let repeats = count(1, 20);
        assert!(repeats("0").is_err() && repeats("-1").is_err() && repeats("21").is_err());
        assert_eq!(repeats("3"), Ok(3));
    }
}
