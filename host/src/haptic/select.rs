//! Sample selection for the joint-angle calibration (paper §2.2): k-means with N centroids
//! initialised from N randomly picked measurements (seeded), a few Lloyd iterations, then the
//! real sample nearest each centroid. Re-run with another seed each iteration, it gives a
//! varying, evenly spread selection. The nearest-sample look-up is a linear scan: with a few
//! thousand samples and 200 centroids it is as fast as a KD-tree would be.

use nalgebra::Vector3;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Lloyd iterations.
const ITERATIONS: usize = 8;
/// Most points the centroids are fitted to (an even stride of the samples); the nearest real
/// sample is then looked up among all of them.
const MAX_FIT_POINTS: usize = 1500;

/// Indices of up to `n` samples spread over `points` (sorted, without repeats).
pub fn kmeans_select(points: &[Vector3<f64>], n: usize, seed: u64) -> Vec<usize> {
    if points.len() <= n {
        return (0..points.len()).collect();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.shuffle(&mut rng);
    let mut centroids: Vec<Vector3<f64>> = order[..n].iter().map(|&i| points[i]).collect();
    // Nearest centroid by a plain loop over squared distances (the hot spot of the pipeline).
    let nearest = |p: &Vector3<f64>, cs: &[Vector3<f64>]| {
        let (mut best, mut best_d) = (0, f64::INFINITY);
        for (i, c) in cs.iter().enumerate() {
            let (dx, dy, dz) = (c.x - p.x, c.y - p.y, c.z - p.z);
            let d = dx * dx + dy * dy + dz * dz;
            if d < best_d {
                best_d = d;
                best = i;
            }
        }
        best
    };
    let stride = points.len().div_ceil(MAX_FIT_POINTS).max(1);
    for _ in 0..ITERATIONS {
        let mut sums = vec![(Vector3::zeros(), 0usize); n];
        for p in points.iter().step_by(stride) {
            let c = nearest(p, &centroids);
            sums[c].0 += p;
            sums[c].1 += 1;
        }
        for (c, (sum, count)) in centroids.iter_mut().zip(&sums) {
            if *count > 0 {
                *c = sum / *count as f64;
            }
        }
    }
    let mut chosen: Vec<usize> = centroids.iter().map(|c| nearest(c, points)).collect();
    chosen.sort_unstable();
    chosen.dedup();
    chosen
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selects_a_seeded_spread_of_real_samples() {
        // Dense cluster plus a sparse line: the selection must reach the sparse part too.
        let mut points: Vec<Vector3<f64>> =
            (0..2000).map(|k| Vector3::new((k % 40) as f64 * 0.1, (k / 40) as f64 * 0.1, 0.0)).collect();
        points.extend((0..50).map(|k| Vector3::new(100.0 + k as f64 * 4.0, 0.0, 0.0)));
        let a = kmeans_select(&points, 100, 7);
        assert_eq!(a, kmeans_select(&points, 100, 7), "seeded");
        assert!(a.len() > 80 && a.len() <= 100);
        // k-means follows the density of the samples; the sparse part is still reached.
        let far = a.iter().filter(|&&i| i >= 2000).count();
        assert!(far >= 1, "the sparse line is represented: {far}");
        assert_ne!(a, kmeans_select(&points, 100, 8), "another seed, another selection");
    }
}
