//! What a solution reports: the residuals per kind, the floated tools, the estimates with their
//! standard deviations and the strong correlations.

use super::*;

/// The residual statistics per kind from the residuals `r` of `problem`'s terms.
pub(super) fn residual_stats(problem: &Problem, r: &[f64]) -> FitStats {
    let (mut distances, mut points, mut angles) = (Vec::new(), Vec::new(), Vec::new());
    for (t, &at) in problem.terms().iter().zip(problem.offsets()) {
        let rows = &r[at..at + t.rows()];
        let size = || Vector3::new(rows[0], rows[1], rows[2]).norm() / t.weight();
        match (t.rows(), t.is_position()) {
            (1, true) => distances.push(rows[0]),
            (3, true) => points.push(size()),
            (3, false) => angles.push(size().to_degrees()),
            _ => {}
        }
    }
    FitStats {
        distances: (!distances.is_empty()).then(|| ErrorStats::of(&distances)),
        points: (!points.is_empty()).then(|| ErrorStats::of(&points)),
        orientations: (!angles.is_empty()).then(|| AngleStats::of(&angles)),
    }
}

pub(super) fn covariance_block(cov: Option<&nalgebra::DMatrix<f64>>, at: usize) -> Matrix3<f64> {
    cov.map_or(Matrix3::zeros(), |c| c.fixed_view::<3, 3>(at, at).into_owned())
}

/// Each floated group's tool offset with the deviation of its length.
pub(super) fn floated_tools(
    problem: &Problem,
    data: &Observations,
    tools: &[Vector3<f64>],
    cov: Option<&nalgebra::DMatrix<f64>>,
) -> Vec<FloatedTool> {
    (0..data.groups.len())
        .filter_map(|g| {
            let c = problem.layout.tool_column(g)?;
            Some(FloatedTool::new(data.groups[g].name.clone(), &tools[g], &covariance_block(cov, c)))
        })
        .collect()
}

/// Every free parameter's estimate: its value in `model`, its std when estimated.
pub(super) fn estimates(
    nominal: &ArmModel,
    model: &ArmModel,
    all: &[ParamId],
    estimated: &[ParamId],
    cov: Option<&nalgebra::DMatrix<f64>>,
) -> Vec<Estimate> {
    all.iter()
        .map(|&id| {
            let k = estimated.iter().position(|e| *e == id);
            Estimate {
                param: nominal.param_name(id),
                unit: id.unit().to_string(),
                nominal: nominal.get(id),
                value: model.get(id),
                std: k.and_then(|k| cov.map(|c| c[(k, k)].max(0.0).sqrt())),
                status: if k.is_some() { "estimated".into() } else { "fixed: unidentifiable".into() },
            }
        })
        .collect()
}

/// Estimated pairs correlated beyond ±0.9.
pub(super) fn correlations(
    model: &ArmModel,
    estimated: &[ParamId],
    cov: Option<&nalgebra::DMatrix<f64>>,
) -> Vec<(String, String, f64)> {
    let mut out = Vec::new();
    if let Some(c) = cov {
        let n = estimated.len();
        for a in 0..n {
            for b in a + 1..n {
                let rho = c[(a, b)] / (c[(a, a)] * c[(b, b)]).sqrt();
                if rho.abs() > 0.9 {
                    out.push((model.param_name(estimated[a]), model.param_name(estimated[b]), rho));
                }
            }
        }
    }
    out
}
