//! The HTML pages a person opens: one file per report, plots in [`svg`]. Reports read results and
//! never recompute them.

pub mod auto;
pub mod certificate;
pub mod compare;
pub mod diagnosis;
pub mod dynamic;
pub mod haptic;
pub mod run;
pub mod study;
pub mod svg;

use std::fmt::Write;
use svg::escape;

const STYLE: &str = "body{font-family:sans-serif;max-width:1000px;margin:2em auto;color:#222}table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}th{background:#f4f4f4}td:first-child{text-align:left}.flag{color:#b00;font-weight:bold}figure{display:inline-block;margin:4px}";

/// Wrap body HTML into a page.
pub fn page(title: &str, body: &str) -> String {
    let mut html = page_start(title);
    html.push_str(body);
    page_end(html)
}

/// A page's text up to its body, for a report that writes its body after it (a large page is then
/// not copied into [`page`]'s); [`page_end`] closes it.
pub(crate) fn page_start(title: &str) -> String {
    format!("<!doctype html><html><head><meta charset=\"utf-8\"><title>{t}</title><style>{STYLE}</style></head><body><h1>{t}</h1>", t = escape(title))
}

/// Close a page begun with [`page_start`].
pub(crate) fn page_end(mut html: String) -> String {
    html.push_str("</body></html>");
    html
}

/// HTML table from a header and rows of already formatted cells.
pub fn table(header: &[&str], rows: &[Vec<String>]) -> String {
    let mut out = String::from("<table><tr>");
    for h in header {
        let _ = write!(out, "<th>{}</th>", escape(h));
    }
    out.push_str("</tr>");
    for row in rows {
        out.push_str("<tr>");
        for cell in row {
            let _ = write!(out, "<td>{cell}</td>");
        }
        out.push_str("</tr>");
    }
    out + "</table>"
}

/// A length in millimetres as the reports print it.
pub fn mm(v: f64) -> String {
    format!("{v:.3}")
}
