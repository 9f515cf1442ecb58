//! Progress shown while a long step runs.

use indicatif::{ProgressBar, ProgressStyle};

/// A spinner with the elapsed time on stderr while a long step runs (hidden when stderr is not
/// a terminal).
pub fn spinner(what: &str) -> ProgressBar {
    let bar = ProgressBar::new_spinner();
    if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} ({elapsed})") {
        bar.set_style(style);
    }
    bar.set_message(what.to_string());
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}
