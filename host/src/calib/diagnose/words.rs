//! How the diagnosis writes its figures.

/// A length as the diagnosis writes it: three decimals from 0.1 mm, four below.
pub fn mm(v: f64) -> String {
    if v.abs() >= 0.1 {
        format!("{v:.3}")
    } else {
        format!("{v:.4}")
    }
}
