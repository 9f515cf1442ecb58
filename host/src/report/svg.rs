//! Minimal SVG charts for self-contained HTML reports (no scripts, no external files).

use std::fmt::Write;

/// Series colours, colour-blind friendly.
pub const COLORS: [&str; 4] = ["#d55e00", "#0072b2", "#009e73", "#cc79a7"];

/// Plot area in pixels.
struct Frame {
    width: f64,
    height: f64,
    left: f64,
    bottom: f64,
    x: (f64, f64),
    y: (f64, f64),
}

impl Frame {
    fn new(width: f64, height: f64, x: (f64, f64), y: (f64, f64)) -> Frame {
        let pad = |(a, b): (f64, f64)| if (b - a).abs() < 1e-12 { (a - 0.5, b + 0.5) } else { (a, b) };
        Frame { width, height, left: 56.0, bottom: 36.0, x: nice_range(pad(x)), y: nice_range(pad(y)) }
    }
    fn px(&self, x: f64) -> f64 {
        on_canvas(self.left + (x - self.x.0) / (self.x.1 - self.x.0) * (self.width - self.left - 12.0))
    }
    fn py(&self, y: f64) -> f64 {
        on_canvas(12.0 + (self.y.1 - y) / (self.y.1 - self.y.0) * (self.height - self.bottom - 12.0))
    }
    fn open(&self, out: &mut String, x_label: &str, y_label: &str, x_ticks: bool) {
        let _ = write!(
            out,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="11">"#,
            w = self.width,
            h = self.height
        );
        let (x0, x1, y0, y1) = (self.px(self.x.0), self.px(self.x.1), self.py(self.y.0), self.py(self.y.1));
        let _ = write!(
            out,
            r##"<rect x="{x0}" y="{y1}" width="{}" height="{}" fill="none" stroke="#888"/>"##,
            x1 - x0,
            y0 - y1
        );
        // Each figure the ticks repeat is formatted once (a page has a hundred plots).
        let (left, right, label_x) = (x0.to_string(), x1.to_string(), (x0 - 4.0).to_string());
        for v in nice_ticks(self.y) {
            let y = self.py(v);
            let y_text = y.to_string();
            let _ = write!(
                out,
                r##"<line x1="{left}" x2="{right}" y1="{y_text}" y2="{y_text}" stroke="#eee"/><text x="{label_x}" y="{}" text-anchor="end">{}</text>"##,
                y + 4.0,
                tick(v, self.y)
            );
        }
        if x_ticks {
            let label_y = (y0 + 14.0).to_string();
            for u in nice_ticks(self.x) {
                let _ = write!(
                    out,
                    r#"<text x="{}" y="{label_y}" text-anchor="middle">{}</text>"#,
                    self.px(u),
                    tick(u, self.x)
                );
            }
        }
        let _ = write!(
            out,
            r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
            (x0 + x1) / 2.0,
            self.height - 4.0,
            escape(x_label)
        );
        let _ = write!(
            out,
            r#"<text transform="translate(12,{}) rotate(-90)" text-anchor="middle">{}</text>"#,
            (y0 + y1) / 2.0,
            escape(y_label)
        );
    }
}

/// Largest magnitude a chart takes as a value to draw; beyond it (or not finite) a value is left
/// out of the axis range, so one absurd value cannot turn every coordinate into `inf`.
pub const PLOTTABLE: f64 = 1e12;

/// The pixel coordinate `px` in tenths, rounded as `{:.1}` writes it, and whether a minus sign
/// leads it (`-0.0` has one, as in the formatter's text); `None` where only the formatter can tell
/// (not finite, or beyond 10¹⁵ tenths). The formatter's exact decimal expansion is costly: a
/// scatter plot writes two coordinates per point and the plots of a 3 600-point run were a
/// fourteenth of its instructions. The rounded product |px|·10 differs from the exact one's
/// rounding only where it lands on a half (halves are exact in binary and rounding is monotone);
/// there the product's rounding error, exact as 2|px| − (|px|·10 − 8|px|) (both terms exact
/// multiples by powers of two, the larger first: Fast2Sum), says to which side the exact product
/// lies, and an exact half goes to the even tenth as the formatter's does. Below 10¹⁵ the
/// product's whole part and fraction are exact in `f64`, so the rounding is integer arithmetic
/// (no `round` call, a library call on the baseline x86-64 target).
fn tenths(px: f64) -> Option<(bool, u64)> {
    let magnitude = px.abs();
    let scaled = magnitude * 10.0;
    if scaled.is_nan() || scaled >= 1e15 {
        return None;
    }
    // Through `i64`: the conversions of an unsigned integer take several instructions on x86-64.
    let whole = scaled as i64;
    let fraction = scaled - whole as f64;
    let up = if fraction == 0.5 {
        let error = 2.0 * magnitude - (scaled - 8.0 * magnitude);
        error > 0.0 || (error == 0.0 && whole % 2 == 1)
    } else {
        fraction > 0.5
    };
    Some((px.is_sign_negative(), whole.unsigned_abs() + u64::from(up)))
}

/// A plot's points, `<circle>` elements and the like, as bytes, put on the page at once by
/// [`Dots::finish`]. A page of scatter plots is mostly these elements (a tracker run's report:
/// 48 000 of them). Digits written as bytes must be checked as UTF-8 before a `String` takes
/// them, and a copy of a piece of varying length is a library call: so each element is put
/// together in a buffer of fixed size, copied whole, and the plot's text is checked once.
struct Dots {
    bytes: Vec<u8>,
    /// The rest of each circle element after its coordinates.
    tail: String,
    /// The tail padded to a fixed size, when it fits.
    padded_tail: Option<[u8; TAIL_BYTES]>,
}

/// Longest tail of a circle element [`Dots`] copies as a block; a longer one is copied as it is.
const TAIL_BYTES: usize = 64;
/// The buffer of one element: `<circle cx="` (12 bytes), two coordinates of at most 18 bytes
/// each, `" cy="` and `" ` (8 bytes), the tail, and room for a coordinate written as a block.
const ELEMENT_BYTES: usize = 12 + 2 * 18 + 8 + TAIL_BYTES + 8;

impl Dots {
    /// Room for about `points` circle elements, each ending in `tail`.
    fn new(points: usize, tail: &str) -> Dots {
        let padded_tail = (tail.len() <= TAIL_BYTES).then(|| {
            let mut padded = [0; TAIL_BYTES];
            padded[..tail.len()].copy_from_slice(tail.as_bytes());
            padded
        });
        Dots { bytes: Vec::with_capacity(points * (48 + tail.len())), tail: tail.to_string(), padded_tail }
    }

    /// Append `<circle cx="X" cy="Y" ` and the tail, the coordinates as `{:.1}` writes them.
    fn circle(&mut self, cx: f64, cy: f64) {
        let mut text = [0u8; ELEMENT_BYTES];
        text[..12].copy_from_slice(br#"<circle cx=""#);
        let written = put_tenths(&mut text, 12, cx).and_then(|len| {
            text[len..len + 6].copy_from_slice(br#"" cy=""#);
            put_tenths(&mut text, len + 6, cy)
        });
        let Some(len) = written else {
            let head = format!(r#"<circle cx="{cx:.1}" cy="{cy:.1}" "#);
            self.bytes.extend_from_slice(head.as_bytes());
            self.bytes.extend_from_slice(self.tail.as_bytes());
            return;
        };
        text[len..len + 2].copy_from_slice(br#"" "#);
        let len = len + 2;
        match &self.padded_tail {
            Some(padded) => {
                text[len..len + TAIL_BYTES].copy_from_slice(padded);
                let start = self.bytes.len();
                self.bytes.extend_from_slice(&text);
                self.bytes.truncate(start + len + self.tail.len());
            }
            None => {
                self.bytes.extend_from_slice(&text[..len]);
                self.bytes.extend_from_slice(self.tail.as_bytes());
            }
        }
    }

    /// Put the plot's points on the page. Every piece written is text, so the bytes are text;
    /// `from_utf8_lossy` would check them a byte at a time, `from_utf8` a word at a time.
    fn finish(self, out: &mut String) {
        match std::str::from_utf8(&self.bytes) {
            Ok(text) => out.push_str(text),
            // Not reached (every piece is text); kept so that a mistake costs a character, not a panic.
            Err(_) => out.push_str(&String::from_utf8_lossy(&self.bytes)),
        }
    }
}

impl Write for Dots {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        self.bytes.extend_from_slice(s.as_bytes());
        Ok(())
    }
}

/// Write the pixel coordinate `px` into `text` at `at` as `{:.1}` writes it, by [`tenths`];
/// where the text ends, or `None` where only the formatter can tell. It takes at most 18 bytes
/// (a sign, 15 digits, the point and a tenth) and may write a byte beyond its end.
#[inline]
fn put_tenths(text: &mut [u8; ELEMENT_BYTES], at: usize, px: f64) -> Option<usize> {
    let (negative, tenths) = tenths(px)?;
    let at = if negative {
        text[at] = b'-';
        at + 1
    } else {
        at
    };
    if tenths < 10_000 {
        // Below 1000 px (every coordinate of a plot in its frame): the whole part and the point
        // from a table, written as a block.
        let whole = (tenths / 10) as usize;
        text[at..at + 4].copy_from_slice(&WHOLE_AND_POINT[whole]);
        let end = at + 2 + usize::from(whole >= 10) + usize::from(whole >= 100);
        text[end] = b'0' + (tenths % 10) as u8;
        return Some(end + 1);
    }
    let mut whole = tenths / 10;
    let digits = 1 + POWERS_OF_TEN.iter().take_while(|&&p| whole >= p).count();
    let end = at + digits;
    for slot in text[at..end].iter_mut().rev() {
        *slot = b'0' + (whole % 10) as u8;
        whole /= 10;
    }
    text[end] = b'.';
    text[end + 1] = b'0' + (tenths % 10) as u8;
    Some(end + 2)
}

/// The text of each whole number below 1000 and a point after it (`5.`, `42.`, `123.`), padded
/// to four bytes.
const WHOLE_AND_POINT: [[u8; 4]; 1000] = {
    let mut table = [[0u8; 4]; 1000];
    let mut n = 0;
    while n < 1000 {
        table[n] = if n < 10 {
            [ascii_digit(n), b'.', 0, 0]
        } else if n < 100 {
            [ascii_digit(n / 10), ascii_digit(n), b'.', 0]
        } else {
            [ascii_digit(n / 100), ascii_digit(n / 10), ascii_digit(n), b'.']
        };
        n += 1;
    }
    table
};

/// The last decimal digit of `n` as ASCII.
const fn ascii_digit(n: usize) -> u8 {
    b'0' + (n % 10) as u8
}

/// 10, 100, … 10¹⁴: a whole number of tenths below 10¹⁵ has at most 15 digits before the point.
const POWERS_OF_TEN: [u64; 14] = {
    let mut powers = [10u64; 14];
    let mut k = 1;
    while k < powers.len() {
        powers[k] = powers[k - 1] * 10;
        k += 1;
    }
    powers
};

/// A pixel coordinate that SVG can hold: never `inf` or `NaN`, even for a value outside the
/// axis range (it lands far off the canvas instead).
fn on_canvas(px: f64) -> f64 {
    if px.is_nan() {
        0.0
    } else {
        px.clamp(-1e6, 1e6)
    }
}

/// Step of about five ticks over `span`: 1, 2 or 5 times a power of ten.
fn nice_step(span: f64) -> f64 {
    let raw = (span / 5.0).abs().max(1e-12);
    let power = 10f64.powf(raw.log10().floor());
    let m = raw / power;
    power
        * if m < 1.5 {
            1.0
        } else if m < 3.5 {
            2.0
        } else if m < 7.5 {
            5.0
        } else {
            10.0
        }
}

/// Tick values on 1-2-5 steps inside `range`.
fn nice_ticks(range: (f64, f64)) -> Vec<f64> {
    let step = nice_step(range.1 - range.0);
    let first = (range.0 / step - 1e-9).ceil() as i64;
    let last = (range.1 / step + 1e-9).floor() as i64;
    (first..=last).map(|k| k as f64 * step).map(|v| if v.abs() < step * 1e-9 { 0.0 } else { v }).collect()
}

/// `range` widened to whole 1-2-5 steps.
fn nice_range(range: (f64, f64)) -> (f64, f64) {
    if !(range.1 - range.0).is_normal() {
        return range;
    }
    let step = nice_step(range.1 - range.0);
    ((range.0 / step).floor() * step, (range.1 / step).ceil() * step)
}

/// A tick label with as many decimals as the step needs.
fn tick(v: f64, range: (f64, f64)) -> String {
    if !v.is_finite() {
        return "–".into();
    }
    let step = nice_step(range.1 - range.0);
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    format!("{v:.decimals$}")
}

/// Escape text for HTML/SVG.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

fn legend(out: &mut String, frame: &Frame, names: &[&str]) {
    for (k, name) in names.iter().enumerate() {
        let x = frame.width - 170.0;
        let y = 22.0 + 16.0 * k as f64;
        let _ = write!(
            out,
            r#"<rect x="{x}" y="{}" width="10" height="10" fill="{}"/><text x="{}" y="{}">{}</text>"#,
            y - 9.0,
            COLORS[k % COLORS.len()],
            x + 14.0,
            y,
            escape(name)
        );
    }
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values
        .filter(|v| v.abs() <= PLOTTABLE)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)))
}

/// Overlaid histograms of several series over a common range.
pub fn histogram(series: &[(&str, &[f64])], bins: usize, x_label: &str) -> String {
    let (lo, hi) = range(series.iter().flat_map(|(_, v)| v.iter().copied()));
    if !lo.is_finite() {
        return String::new();
    }
    let width = (hi - lo).max(1e-9) / bins as f64;
    let counts: Vec<Vec<usize>> = series
        .iter()
        .map(|(_, v)| {
            let mut c = vec![0; bins];
            for x in v.iter().filter(|x| x.abs() <= PLOTTABLE) {
                c[(((x - lo) / width) as usize).min(bins - 1)] += 1;
            }
            c
        })
        .collect();
    let top = counts.iter().flatten().copied().max().unwrap_or(1) as f64;
    let frame = Frame::new(640.0, 280.0, (lo, hi), (0.0, top));
    let mut out = String::new();
    frame.open(&mut out, x_label, "count", true);
    for (k, c) in counts.iter().enumerate() {
        for (b, &n) in c.iter().enumerate() {
            let (x0, x1) = (frame.px(lo + width * b as f64), frame.px(lo + width * (b + 1) as f64));
            let _ = write!(
                out,
                r#"<rect x="{x0}" y="{}" width="{}" height="{}" fill="{}" fill-opacity="0.55"/>"#,
                frame.py(n as f64),
                (x1 - x0).max(0.5),
                frame.py(0.0) - frame.py(n as f64),
                COLORS[k % COLORS.len()]
            );
        }
    }
    legend(&mut out, &frame, &series.iter().map(|s| s.0).collect::<Vec<_>>());
    out + "</svg>"
}

/// Grouped bars: one group per category, one bar per series; room above the bars for the legend.
pub fn bars(categories: &[String], series: &[(&str, Vec<f64>)], y_label: &str) -> String {
    let tallest = range(series.iter().flat_map(|(_, v)| v.iter().copied())).1.max(1e-9);
    let top = tallest * (1.0 + 0.12 * series.len() as f64);
    let frame = Frame::new(640.0, 280.0, (0.0, categories.len().max(1) as f64), (0.0, top));
    let mut out = String::new();
    frame.open(&mut out, "", y_label, false);
    let group = frame.px(1.0) - frame.px(0.0);
    let bar = group * 0.8 / series.len().max(1) as f64;
    for (i, name) in categories.iter().enumerate() {
        for (k, (_, values)) in series.iter().enumerate() {
            let v = values.get(i).copied().unwrap_or(0.0);
            let x = frame.px(i as f64) + group * 0.1 + bar * k as f64;
            let _ = write!(
                out,
                r#"<rect x="{x}" y="{}" width="{bar}" height="{}" fill="{}"/>"#,
                frame.py(v),
                frame.py(0.0) - frame.py(v),
                COLORS[k % COLORS.len()]
            );
        }
        let _ = write!(
            out,
            r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
            frame.px(i as f64 + 0.5),
            frame.py(0.0) + 14.0,
            escape(name)
        );
    }
    legend(&mut out, &frame, &series.iter().map(|s| s.0).collect::<Vec<_>>());
    out + "</svg>"
}

/// Robust axis range of `values`: the 2nd to 98th percentile widened by half its span, never
/// beyond the data. Points outside are drawn at the edge and counted.
pub(crate) fn robust_range(values: &[f64]) -> (f64, f64) {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.abs() <= PLOTTABLE).collect();
    if v.is_empty() {
        return (f64::INFINITY, f64::NEG_INFINITY);
    }
    let rank = |p: f64| ((v.len() - 1) as f64 * p).round() as usize;
    let (low_rank, high_rank) = (rank(0.02), rank(0.98));
    // The second rank is selected among the values above the first, and each extreme among the
    // values beyond its rank: no pass over all of them after the first selection. Values equal
    // in the total order are the same bits, so the figures are those of a full sort.
    let smaller = |a: f64, b: f64| if b.total_cmp(&a).is_lt() { b } else { a };
    let larger = |a: f64, b: f64| if b.total_cmp(&a).is_gt() { b } else { a };
    let (below, &mut lo, above) = v.select_nth_unstable_by(low_rank, f64::total_cmp);
    let first = below.iter().copied().fold(lo, smaller);
    let (hi, last) = if high_rank == low_rank {
        (lo, above.iter().copied().fold(lo, larger))
    } else {
        let (_, &mut hi, top) = above.select_nth_unstable_by(high_rank - low_rank - 1, f64::total_cmp);
        (hi, top.iter().copied().fold(hi, larger))
    };
    let margin = 0.5 * (hi - lo);
    ((lo - margin).max(first), (hi + margin).min(last))
}

/// Scatter plot, optionally with a line drawn through `curve` points. The y axis is robust: a
/// few far points (a touch near a singularity) are drawn as triangles at the edge, and the plot
/// says how many.
pub fn scatter(points: &[(f64, f64)], curve: &[(f64, f64)], x_label: &str, y_label: &str) -> String {
    let mut out = String::new();
    scatter_into(&mut out, points, curve, x_label, y_label);
    out
}

/// [`scatter`] written at the end of `out` (a page holding many plots is written once, not
/// copied from each plot); false when there is nothing to draw (and nothing was written).
pub fn scatter_into(
    out: &mut String,
    points: &[(f64, f64)],
    curve: &[(f64, f64)],
    x_label: &str,
    y_label: &str,
) -> bool {
    let ys: Vec<f64> = points.iter().chain(curve).map(|p| p.1).collect();
    scatter_on_into(out, points, curve, x_label, y_label, robust_range(&ys))
}

/// [`scatter`] on a given y axis `(y0, y1)`, so that plots side by side share it.
pub fn scatter_on(
    points: &[(f64, f64)],
    curve: &[(f64, f64)],
    x_label: &str,
    y_label: &str,
    y_range: (f64, f64),
) -> String {
    let mut out = String::new();
    scatter_on_into(&mut out, points, curve, x_label, y_label, y_range);
    out
}

/// [`scatter_on`] written at the end of `out`; false when there is nothing to draw.
fn scatter_on_into(
    out: &mut String,
    points: &[(f64, f64)],
    curve: &[(f64, f64)],
    x_label: &str,
    y_label: &str,
    (y0, y1): (f64, f64),
) -> bool {
    let (x0, x1) = range(points.iter().map(|p| p.0));
    if !x0.is_finite() || !y0.is_finite() {
        return false;
    }
    let frame = Frame::new(310.0, 210.0, (x0, x1), (y0, y1));
    // A point is one circle of about 40 bytes.
    out.reserve(2048 + 40 * points.len());
    frame.open(out, x_label, y_label, true);
    // The dots' fill in one group around them, not on each dot (it was 59 % of a page's bytes).
    let _ = write!(out, r#"<g fill="{}" fill-opacity="0.5">"#, COLORS[1]);
    let mut beyond = 0;
    let mut dots = Dots::new(points.len(), r#"r="1.6"/>"#);
    for (x, y) in points {
        let clipped = y.clamp(frame.y.0, frame.y.1);
        if clipped != *y {
            beyond += 1;
            let (cx, cy) = (frame.px(*x), frame.py(clipped));
            let dir = if *y > clipped { -1.0 } else { 1.0 };
            let _ = write!(
                dots,
                r#"<polygon points="{:.1},{:.1} {:.1},{:.1} {:.1},{:.1}" fill="{}" fill-opacity="1"/>"#,
                cx,
                cy + dir * 0.5,
                cx - 3.5,
                cy - dir * 6.0,
                cx + 3.5,
                cy - dir * 6.0,
                COLORS[0]
            );
            continue;
        }
        dots.circle(frame.px(*x), frame.py(*y));
    }
    dots.finish(out);
    out.push_str("</g>");
    // The curve as polylines, broken where its x steps jump (a gap in the data).
    let step = curve.windows(2).map(|w| w[1].0 - w[0].0).filter(|d| *d > 0.0).fold(f64::INFINITY, f64::min);
    let mut runs: Vec<Vec<(f64, f64)>> = Vec::new();
    for (k, p) in curve.iter().enumerate().filter(|(_, p)| (frame.x.0..=frame.x.1).contains(&p.0)) {
        let joined = k > 0 && curve[k].0 - curve[k - 1].0 <= 1.5 * step;
        match runs.last_mut() {
            Some(run) if joined => run.push(*p),
            _ => runs.push(vec![*p]),
        }
    }
    for run in runs.iter().filter(|r| r.len() > 1) {
        let path: Vec<String> = run
            .iter()
            .map(|(x, y)| format!("{:.1},{:.1}", frame.px(*x), frame.py(y.clamp(frame.y.0, frame.y.1))))
            .collect();
        let _ = write!(
            out,
            r#"<polyline points="{}" fill="none" stroke="{}" stroke-width="2"/>"#,
            path.join(" "),
            COLORS[0]
        );
    }
    if beyond > 0 {
        let _ = write!(
            out,
            r#"<text x="{:.1}" y="24" font-size="10" fill="{}">{beyond} point{} beyond the axis, shown at the edge ▲▼</text>"#,
            frame.px(frame.x.0) + 4.0,
            COLORS[0],
            if beyond == 1 { "" } else { "s" }
        );
    }
    out.push_str("</svg>");
    true
}

/// A wide time plot: each series' points in its colour, over thin vertical marks (events such
/// as direction changes); the y axis from zero.
pub fn timeline(series: &[(&str, &[(f64, f64)])], marks: &[f64], x_label: &str, y_label: &str) -> String {
    let all = || series.iter().flat_map(|(_, p)| p.iter());
    let (x0, x1) = range(all().map(|p| p.0));
    let ys: Vec<f64> = all().map(|p| p.1).collect();
    let (_, y1) = robust_range(&ys);
    if !x0.is_finite() || !y1.is_finite() {
        return String::new();
    }
    let frame = Frame::new(940.0, 240.0, (x0, x1), (0.0, y1));
    let mut out = String::new();
    frame.open(&mut out, x_label, y_label, true);
    for &m in marks.iter().filter(|m| (frame.x.0..=frame.x.1).contains(*m)) {
        let _ = write!(
            out,
            r##"<line x1="{x:.1}" x2="{x:.1}" y1="{}" y2="{}" stroke="#bbb" stroke-dasharray="3,3"/>"##,
            frame.py(frame.y.1),
            frame.py(frame.y.0),
            x = frame.px(m)
        );
    }
    for (k, (_, points)) in series.iter().enumerate() {
        let _ = write!(out, r#"<g fill="{}" fill-opacity="0.6">"#, COLORS[k % COLORS.len()]);
        let mut dots = Dots::new(points.len(), r#"r="1.6"/>"#);
        for (x, y) in points.iter() {
            dots.circle(frame.px(*x), frame.py(y.clamp(frame.y.0, frame.y.1)));
        }
        dots.finish(&mut out);
        out.push_str("</g>");
    }
    legend(&mut out, &frame, &series.iter().map(|s| s.0).collect::<Vec<_>>());
    out + "</svg>"
}

/// Horizontal bars, one per row (name, value, highlighted), against labelled reference lines
/// (name, value) such as the noise floor.
pub fn hbars(rows: &[(String, f64, bool)], references: &[(&str, f64)], x_label: &str) -> String {
    let top = rows.iter().map(|r| r.1).chain(references.iter().map(|r| r.1)).fold(0.0, f64::max).max(1e-9);
    let (width, row_h) = (640.0, 18.0);
    let label_w = 150.0;
    let height = 50.0 + row_h * rows.len() as f64 + 14.0 * references.len() as f64;
    let x_range = nice_range((0.0, top));
    let px = |v: f64| label_w + v / x_range.1 * (width - label_w - 60.0);
    let mut out = String::new();
    let _ = write!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="sans-serif" font-size="11">"#
    );
    let bottom = 10.0 + row_h * rows.len() as f64;
    for v in nice_ticks(x_range) {
        let _ = write!(
            out,
            r##"<line x1="{x}" x2="{x}" y1="10" y2="{bottom}" stroke="#eee"/><text x="{x}" y="{}" text-anchor="middle">{}</text>"##,
            bottom + 13.0,
            tick(v, x_range),
            x = px(v)
        );
    }
    for (k, (name, value, strong)) in rows.iter().enumerate() {
        let y = 10.0 + row_h * k as f64;
        let _ = write!(
            out,
            r#"<text x="{}" y="{}" text-anchor="end">{}</text><rect x="{label_w}" y="{}" width="{:.1}" height="{}" fill="{}"/><text x="{:.1}" y="{}">{:.3}</text>"#,
            label_w - 6.0,
            y + 12.0,
            escape(name),
            y + 3.0,
            (px(*value) - label_w).max(0.5),
            row_h - 6.0,
            if *strong { COLORS[0] } else { COLORS[1] },
            px(*value) + 4.0,
            y + 12.0,
            value
        );
    }
    for (k, (name, value)) in references.iter().enumerate() {
        let x = px(*value);
        let _ = write!(
            out,
            r##"<line x1="{x}" x2="{x}" y1="6" y2="{bottom}" stroke="#333" stroke-dasharray="4 3"/><text x="{}" y="{}" fill="#333">dashed: {} {:.3}</text>"##,
            label_w,
            bottom + 28.0 + 14.0 * k as f64,
            escape(name),
            value
        );
    }
    let _ = write!(
        out,
        r#"<text x="{}" y="{}" text-anchor="end">{}</text>"#,
        width - 20.0,
        height - 4.0,
        escape(x_label)
    );
    out + "</svg>"
}

/// Box plot (quartiles, whiskers at min/max) per group.
pub fn boxplot(groups: &[(String, Vec<f64>)], y_label: &str) -> String {
    let (lo, hi) = range(groups.iter().flat_map(|(_, v)| v.iter().copied()));
    if !lo.is_finite() {
        return String::new();
    }
    let frame = Frame::new(640.0, 280.0, (0.0, groups.len() as f64), (lo.min(0.0), hi));
    let mut out = String::new();
    frame.open(&mut out, "placements used for calibration", y_label, false);
    for (i, (name, values)) in groups.iter().enumerate() {
        let mut v: Vec<f64> = values.iter().copied().filter(|x| x.abs() <= PLOTTABLE).collect();
        if v.is_empty() {
            continue;
        }
        v.sort_by(f64::total_cmp);
        let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
        let (cx, w) = (frame.px(i as f64 + 0.5), (frame.px(1.0) - frame.px(0.0)) * 0.3);
        let _ = write!(
            out,
            r##"<line x1="{cx}" x2="{cx}" y1="{}" y2="{}" stroke="#333"/>"##,
            frame.py(q(0.0)),
            frame.py(q(1.0))
        );
        let _ = write!(
            out,
            r##"<rect x="{}" y="{}" width="{}" height="{}" fill="{}" stroke="#333"/>"##,
            cx - w / 2.0,
            frame.py(q(0.75)),
            w,
            (frame.py(q(0.25)) - frame.py(q(0.75))).max(0.5),
            COLORS[1]
        );
        let _ = write!(
            out,
            r##"<line x1="{}" x2="{}" y1="{m}" y2="{m}" stroke="#fff" stroke-width="2"/>"##,
            cx - w / 2.0,
            cx + w / 2.0,
            m = frame.py(q(0.5))
        );
        let _ = write!(
            out,
            r#"<text x="{cx}" y="{}" text-anchor="middle">{}</text>"#,
            frame.py(frame.y.0) + 14.0,
            escape(name)
        );
    }
    out + "</svg>"
}

/// Directions on a Hammer (equal-area) projection, coloured by value from blue (0) to red (max):
/// longitude = atan2(x, z), latitude = asin(y) of each unit direction.
pub fn hammer_map(points: &[(f64, f64, f64)], label: &str) -> String {
    let (w, h) = (640.0, 340.0);
    let top = points.iter().map(|p| p.2).filter(|v| v.abs() <= PLOTTABLE).fold(1e-12, f64::max);
    let project = |lon: f64, lat: f64| {
        let d = (1.0 + lat.cos() * (lon / 2.0).cos()).sqrt().max(1e-9);
        let x = 2.0 * 2f64.sqrt() * lat.cos() * (lon / 2.0).sin() / d;
        let y = 2f64.sqrt() * lat.sin() / d;
        (
            w / 2.0 + x * (w / 2.0 - 20.0) / (2.0 * 2f64.sqrt()),
            h / 2.0 - 10.0 - y * (h / 2.0 - 30.0) / 2f64.sqrt(),
        )
    };
    let mut out = String::new();
    let _ = write!(
        out,
        r##"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="11"><ellipse cx="{}" cy="{}" rx="{}" ry="{}" fill="#f8f8f8" stroke="#888"/>"##,
        w / 2.0,
        h / 2.0 - 10.0,
        w / 2.0 - 20.0,
        h / 2.0 - 30.0
    );
    let mut dots = Dots::new(points.len(), "");
    for &(lon, lat, v) in points {
        let (x, y) = project(lon, lat);
        let (x, y) = (on_canvas(x), on_canvas(y));
        let f = if v.is_nan() { 0.0 } else { (v / top).clamp(0.0, 1.0) };
        dots.circle(x, y);
        let _ = write!(
            dots,
            r#"r="2.2" fill="rgb({},{},{})"/>"#,
            (255.0 * f) as u8,
            60,
            (255.0 * (1.0 - f)) as u8
        );
    }
    dots.finish(&mut out);
    let _ = write!(
        out,
        r#"<text x="10" y="{}">{} — blue 0, red {:.3}</text></svg>"#,
        h - 6.0,
        escape(label),
        top
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coordinates_are_written_as_the_formatter_writes_them() {
        let written = |px: f64| {
            let tail = r#"r="1"/>"#;
            let mut dots = Dots::new(1, tail);
            dots.circle(px, -px);
            let mut out = String::new();
            dots.finish(&mut out);
            out
        };
        let formatted = |px: f64| format!(r#"<circle cx="{px:.1}" cy="{:.1}" r="1"/>"#, -px);
        let mut rng = 0x2545_f491_4f6c_dd1d_u64;
        for k in 0..40_000 {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            let uniform = (rng >> 11) as f64 / (1u64 << 53) as f64;
            // Half of them on a 0.01 grid, where px·10 often lands on a half.
            let px = if k % 2 == 0 {
                uniform * 2400.0 - 1200.0
            } else {
                (uniform * 240_000.0).round() / 100.0 - 1200.0
            };
            assert_eq!(written(px), formatted(px), "{px}");
        }
        let edges = [
            0.0,
            -0.0,
            0.35,
            0.15,
            0.25,
            -0.25,
            1.45,
            0.05,
            -0.05,
            0.95,
            -0.95,
            9.95,
            99.95,
            -0.04,
            -0.06,
            309.96,
            999_999.95,
            999_999.96,
            -1e6,
            1e6,
            123_456_789.05,
            9.9e13,
            -9.99e13,
            1e14 + 0.25,
            2e14,
            1e16,
            f64::MAX,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        for px in edges {
            assert_eq!(written(px), formatted(px), "{px}");
        }
        // Every tenth below 1000 px, and beside it.
        for tenths in 0..10_000 {
            let px = f64::from(tenths) / 10.0;
            for px in [px, px + 0.03, px - 0.04] {
                assert_eq!(written(px), formatted(px), "{px}");
            }
        }
        // Each count of digits, at and beside its powers of ten.
        for k in 0..15 {
            let power = 10f64.powi(k);
            for px in [power, power - 0.05, power - 0.04, power + 0.04, power + 0.06, 9.96 * power] {
                assert_eq!(written(px), formatted(px), "{px}");
                assert_eq!(written(-px), formatted(-px), "{}", -px);
            }
        }
        // A tail too long for the element's buffer is written after it, and the elements of a
        // plot follow one another.
        for tail in ["x".repeat(TAIL_BYTES), "y".repeat(TAIL_BYTES + 1), String::new()] {
            let mut dots = Dots::new(2, &tail);
            dots.circle(1.25, 2.0);
            dots.circle(-1e7, 999.96);
            let mut out = String::from("<svg>");
            dots.finish(&mut out);
            let expected = format!(
                r#"<svg><circle cx="{:.1}" cy="2.0" {tail}<circle cx="{:.1}" cy="{:.1}" {tail}"#,
                1.25, -1e7, 999.96
            );
            assert_eq!(out, expected);
        }
        // The integer path, not the formatter's, writes these: beside a half the fraction
        // rounds, zero keeps its sign, a product rounded onto a half goes to the exact product's
        // side (0.05 is a little above, 0.15 a little below) and an exact half to the even tenth.
        assert_eq!(tenths(0.26), Some((false, 3)));
        assert_eq!(tenths(-0.04), Some((true, 0)));
        assert_eq!(tenths(-1234.56), Some((true, 12346)));
        assert_eq!(tenths(0.05), Some((false, 1)));
        assert_eq!(tenths(0.15), Some((false, 1)));
        assert_eq!(tenths(0.25), Some((false, 2)));
        assert_eq!(tenths(-0.75), Some((true, 8)));
        assert_eq!(tenths(f64::NAN), None);
        assert_eq!(tenths(f64::INFINITY), None);
        assert_eq!(tenths(1e15), None);
        // Every value near a half of a tenth below 10 000 px (the decimals k/20, most not exact,
        // and their neighbours one ulp away), the exact halves k/4 below 50 000 px, both signs:
        // the integer path writes each (no formatter), as the formatter does.
        let text = |px: f64| {
            let (negative, tenths) = tenths(px).expect("finite and below 10¹⁵ tenths");
            format!("{}{}.{}", if negative { "-" } else { "" }, tenths / 10, tenths % 10)
        };
        for k in 0..200_000u32 {
            let half = f64::from(k) / 20.0;
            for px in [half, f64::from(k) / 4.0, half.next_up(), half.next_down()] {
                for px in [px, -px] {
                    assert_eq!(text(px), format!("{px:.1}"), "{px:e}");
                }
            }
        }
        // Large values near halves (ulps of a tenth and more) likewise.
        for k in 0..40u32 {
            let power = 10f64.powi(i32::try_from(k % 14).unwrap_or(0));
            for px in [power * 1.25, power * 7.75 + 0.05, (power * 3.0 + 0.25).next_up(), power * 9.95] {
                assert_eq!(text(px), format!("{px:.1}"), "{px:e}");
            }
        }
    }

    #[test]
    fn robust_range_keeps_the_middle_and_the_extremes() {
        let mut values: Vec<f64> = (0..101).map(|k| k as f64).collect();
        values.reverse();
        values.push(f64::NAN);
        // 2 % and 98 % of 100 ranks: 2 and 98, a margin of half their span, inside the extremes.
        assert_eq!(robust_range(&values), (0.0, 100.0));
        let mut far = values.clone();
        far[0] = 1e5;
        assert_eq!(robust_range(&far), (0.0, 146.0));
        assert_eq!(robust_range(&[f64::NAN]), (f64::INFINITY, f64::NEG_INFINITY));
        // The same figures, to the bit, as the quantiles and extremes of a full sort.
        let sorted_range = |values: &[f64]| {
            let mut v: Vec<f64> = values.iter().copied().filter(|x| x.abs() <= PLOTTABLE).collect();
            v.sort_by(f64::total_cmp);
            let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
            let (lo, hi) = (q(0.02), q(0.98));
            let margin = 0.5 * (hi - lo);
            ((lo - margin).max(v[0]), (hi + margin).min(v[v.len() - 1]))
        };
        let mut rng = 0x2545_f491_4f6c_dd1d_u64;
        for n in 1..400 {
            let values: Vec<f64> = (0..n)
                .map(|_| {
                    rng ^= rng << 13;
                    rng ^= rng >> 7;
                    rng ^= rng << 17;
                    // Repeated values, both zeros, and values no plot takes.
                    match rng % 16 {
                        0 => -0.0,
                        1 => 0.0,
                        2 => f64::NAN,
                        3 => -1e300,
                        _ => ((rng >> 11) % 64) as f64 - 32.0 + if rng.is_multiple_of(3) { 0.5 } else { 0.0 },
                    }
                })
                .collect();
            let (lo, hi) = robust_range(&values);
            if values.iter().all(|x| x.abs() > PLOTTABLE || x.is_nan()) {
                assert_eq!((lo, hi), (f64::INFINITY, f64::NEG_INFINITY));
                continue;
            }
            let (a, b) = sorted_range(&values);
            assert_eq!((lo.to_bits(), hi.to_bits()), (a.to_bits(), b.to_bits()), "{values:?}");
        }
    }

    #[test]
    fn ticks_are_one_two_five_steps() {
        let labels = |range: (f64, f64)| -> Vec<String> {
            nice_ticks(range).into_iter().map(|v| tick(v, range)).collect()
        };
        assert_eq!(labels((0.0, 1.0)), ["0.0", "0.2", "0.4", "0.6", "0.8", "1.0"]);
        assert_eq!(labels(nice_range((0.35, 359.0))), ["0", "100", "200", "300", "400"]);
        assert_eq!(
            labels(nice_range((-0.089, 0.05))),
            ["-0.10", "-0.08", "-0.06", "-0.04", "-0.02", "0.00", "0.02", "0.04", "0.06"]
        );
        assert_eq!(tick(0.02, (0.0, 0.1)), "0.02");
        assert_eq!(tick(100.0, (0.0, 360.0)), "100");
    }

    #[test]
    fn a_far_point_does_not_squash_the_axis() {
        let mut points: Vec<(f64, f64)> =
            (0..200).map(|k| (k as f64, 0.01 * ((k % 7) as f64 - 3.0))).collect();
        points.push((50.0, 18.7));
        let svg = scatter(&points, &[], "x", "y");
        assert!(svg.contains("1 point beyond the axis"), "{svg}");
        let (lo, hi) = robust_range(&points.iter().map(|p| p.1).collect::<Vec<_>>());
        assert!(hi < 1.0 && lo > -1.0, "{lo} {hi}");
    }

    #[test]
    fn absurd_values_never_reach_the_svg_as_inf_or_nan() {
        let bad = [1.0, 2.5, 1e308, -1e308, f64::INFINITY, f64::NAN, 0.5];
        let points: Vec<(f64, f64)> = bad.iter().map(|&v| (v, -v)).collect();
        let charts = [
            histogram(&[("a", &bad), ("b", &[1.0, 2.0])], 10, "error (mm)"),
            bars(&["x".into(), "y".into()], &[("a", bad.to_vec())], "mm"),
            scatter(&points, &points, "x", "y"),
            boxplot(&[("1".into(), bad.to_vec())], "mm"),
            hammer_map(&[(0.1, 0.2, 1e308), (f64::NAN, 0.0, f64::INFINITY), (0.3, 0.1, 1.0)], "mm"),
        ];
        for svg in &charts {
            assert!(svg.contains("<svg"), "a chart of the finite values is drawn: {svg}");
            for word in ["inf", "NaN", "1e308", "e30"] {
                assert!(!svg.contains(word), "{word} in {svg}");
            }
        }
    }
}
