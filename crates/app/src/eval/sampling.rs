//! Where `eval` puts its points: the foreground of a volume (Otsu's threshold), landmarks drawn at random in it or
//! on its strongest-gradient voxels, and held-out points, all from one seeded generator.
//!
//! - **Foreground**: the voxels whose value is above Otsu's threshold t*, the t that maximises the between-class
//!   variance ω₀ω₁(μ₀ − μ₁)² of a 256-bin histogram spanning the volume's finite values (Otsu 1979). On MRI it
//!   separates tissue from background; on CT, air from the body.
//! - **Random points**: distinct foreground voxels drawn uniformly, each moved to a uniform position inside its voxel
//!   (index ± ½), so the points are continuous and never sit on the grid.
//! - **Feature points** (`--on-features`): the foreground voxels ranked by gradient magnitude ‖∇v‖ (central
//!   differences, in value units per mm), the strongest max(20 N, 2 %) of them shuffled, then accepted greedily
//!   when at least s mm from every point already accepted, starting from s = ½ (V_fg / N)^⅓ (V_fg the foreground
//!   volume in mm³) and halving s until N are placed. Feature points are voxel centres.
//! - **Generator**: SplitMix64 (Steele, Lea & Flood 2014), seeded by (seed, stream); each use has its own stream,
//!   so adding landmarks never moves the held-out points.

use warpbench_io::Volume;
use warpbench_io::geometry::{Index, Point3};

/// Bins of the Otsu histogram.
const OTSU_BINS: usize = 256;

/// A small seeded generator (SplitMix64): deterministic on every platform, no dependency.
#[derive(Clone, Debug)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;

    /// The generator for `seed` and `stream` (streams of one seed are independent for our purposes).
    #[must_use]
    pub fn new(seed: u64, stream: u64) -> Self {
        let mut g = Self(seed);
        let mixed = g.next_u64() ^ stream.wrapping_mul(Self::GOLDEN).rotate_left(17);
        Self(mixed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(Self::GOLDEN);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in 0..n (n > 0), by Lemire's multiply-shift.
    pub fn below(&mut self, n: usize) -> usize {
        ((u128::from(self.next_u64()) * n as u128) >> 64) as usize
    }
}

/// Otsu's threshold of `values` (finite ones only); `None` when fewer than two distinct finite values.
#[must_use]
pub fn otsu_threshold(values: &[f32]) -> Option<f64> {
    let (lo, hi) = values
        .iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| (lo.min(f64::from(v)), hi.max(f64::from(v))));
    if !(lo.is_finite() && hi > lo) {
        return None;
    }
    let width = (hi - lo) / OTSU_BINS as f64;
    let bin = |v: f64| (((v - lo) / width) as usize).min(OTSU_BINS - 1);
    let mut histogram = [0u64; OTSU_BINS];
    for v in values.iter().filter(|v| v.is_finite()) {
        histogram[bin(f64::from(*v))] += 1;
    }
    let total: u64 = histogram.iter().sum();
    let centre = |b: usize| lo + (b as f64 + 0.5) * width;
    let sum_all: f64 = histogram.iter().enumerate().map(|(b, &c)| c as f64 * centre(b)).sum();
    let (mut w0, mut sum0) = (0u64, 0.0);
    let (mut best, mut best_bin) = (f64::NEG_INFINITY, 0);
    for (b, &c) in histogram.iter().enumerate().take(OTSU_BINS - 1) {
        w0 += c;
        sum0 += c as f64 * centre(b);
        let w1 = total - w0;
        if w0 == 0 || w1 == 0 {
            continue;
        }
        let (m0, m1) = (sum0 / w0 as f64, (sum_all - sum0) / w1 as f64);
        let between = w0 as f64 * w1 as f64 * (m0 - m1) * (m0 - m1);
        if between > best {
            (best, best_bin) = (between, b);
        }
    }
    // Values above the upper edge of the best lower class are foreground.
    Some(lo + (best_bin + 1) as f64 * width)
}

/// The linear indices of the voxels of `values` above `threshold`, in increasing order.
#[must_use]
pub fn foreground(values: &[f32], threshold: f64) -> Vec<usize> {
    values.iter().enumerate().filter(|(_, v)| f64::from(**v) > threshold).map(|(i, _)| i).collect()
}

/// (i, j, k) of linear index `i` (x fastest).
#[must_use]
pub fn ijk(dims: [usize; 3], i: usize) -> [usize; 3] {
    [i % dims[0], (i / dims[0]) % dims[1], i / (dims[0] * dims[1])]
}

/// The LPS position of the continuous index `index` of `v`.
fn lps_at(v: &Volume, index: [f64; 3]) -> [f64; 3] {
    v.lps_from_index.apply_point(Point3::<Index>::from_array(index)).coords()
}

/// The centre of voxel `i` of `v`, LPS mm.
#[must_use]
pub fn voxel_centre(v: &Volume, i: usize) -> [f64; 3] {
    lps_at(v, ijk(v.dims, i).map(|c| c as f64))
}

/// `n` distinct voxels of `candidates` drawn uniformly (all of them, in random order, when there are fewer), each
/// at a uniform position inside the voxel, LPS mm. `accept` may refuse a point (it is then skipped); at most
/// `candidates.len()` voxels are tried.
pub fn random_points(
    v: &Volume,
    candidates: &[usize],
    n: usize,
    rng: &mut SplitMix64,
    mut accept: impl FnMut([f64; 3]) -> bool,
) -> Vec<[f64; 3]> {
    // A partial Fisher–Yates shuffle over positions in `candidates`, kept sparse (only swapped slots are stored).
    let mut swapped = std::collections::HashMap::new();
    let mut out = Vec::with_capacity(n);
    for t in 0..candidates.len() {
        if out.len() == n {
            break;
        }
        let r = t + rng.below(candidates.len() - t);
        let at_r = *swapped.get(&r).unwrap_or(&r);
        let at_t = *swapped.get(&t).unwrap_or(&t);
        swapped.insert(r, at_t);
        let [i, j, k] = ijk(v.dims, candidates[at_r]);
        let jitter = [rng.unit() - 0.5, rng.unit() - 0.5, rng.unit() - 0.5];
        let p = lps_at(v, [i as f64 + jitter[0], j as f64 + jitter[1], k as f64 + jitter[2]]);
        if accept(p) {
            out.push(p);
        }
    }
    out
}

/// ‖∇v‖ at voxel `i` by central differences (one-sided at the border), in value units per mm.
fn gradient_magnitude(v: &Volume, values: &[f32], index_from_lps_t: &[[f64; 3]; 3], i: usize) -> f64 {
    let dims = v.dims;
    let c = ijk(dims, i);
    let stride = [1, dims[0], dims[0] * dims[1]];
    let mut g_index = [0.0; 3];
    for a in 0..3 {
        let (lo, hi) = (c[a].saturating_sub(1), (c[a] + 1).min(dims[a] - 1));
        if hi == lo {
            continue;
        }
        let at = |p: usize| f64::from(values[i - c[a] * stride[a] + p * stride[a]]);
        g_index[a] = (at(hi) - at(lo)) / (hi - lo) as f64;
    }
    // ∇_lps v = (∂index/∂lps)ᵀ ∇_index v.
    let g_lps: [f64; 3] = std::array::from_fn(|r| (0..3).map(|c| index_from_lps_t[r][c] * g_index[c]).sum());
    dist(g_lps, [0.0; 3])
}

/// `n` landmark positions on strong-gradient voxels of `candidates` (module docs), LPS mm; fewer only when
/// `accept` refuses too many. `accept` is asked about every point before it is placed.
pub fn feature_points(
    v: &Volume,
    values: &[f32],
    candidates: &[usize],
    n: usize,
    rng: &mut SplitMix64,
    mut accept: impl FnMut([f64; 3]) -> bool,
) -> Vec<[f64; 3]> {
    let linear = v.lps_from_index.linear();
    let Some(index_from_lps) = linear.try_inverse() else { return Vec::new() };
    let t: [[f64; 3]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| index_from_lps[(c, r)]));
    let mut ranked: Vec<(f64, usize)> = candidates.iter().map(|&i| (gradient_magnitude(v, values, &t, i), i)).collect();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let keep = (20 * n).max(candidates.len() / 50).min(ranked.len());
    let mut pool: Vec<usize> = ranked[..keep].iter().map(|&(_, i)| i).collect();
    for s in (1..pool.len()).rev() {
        let r = rng.below(s + 1);
        pool.swap(s, r);
    }
    let voxel_mm3 = linear.determinant().abs();
    let spacing = v.spacing_mm().into_iter().fold(f64::INFINITY, f64::min);
    let mut min_spacing_mm = 0.5 * (candidates.len() as f64 * voxel_mm3 / n.max(1) as f64).cbrt();
    let mut placed: Vec<[f64; 3]> = Vec::with_capacity(n);
    let mut used = vec![false; pool.len()];
    let mut refused = vec![false; pool.len()];
    loop {
        for (slot, &i) in pool.iter().enumerate() {
            if placed.len() == n {
                return placed;
            }
            if used[slot] || refused[slot] {
                continue;
            }
            let p = voxel_centre(v, i);
            let far = placed.iter().all(|q| dist(p, *q) >= min_spacing_mm);
            if far {
                if accept(p) {
                    placed.push(p);
                    used[slot] = true;
                } else {
                    refused[slot] = true;
                }
            }
        }
        if placed.len() == n || min_spacing_mm < 0.25 * spacing {
            return placed;
        }
        min_spacing_mm *= 0.5;
    }
}

/// Euclidean distance, mm.
#[must_use]
pub fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn otsu_splits_two_clusters() {
        let mut values = vec![10.0f32; 500];
        values.extend(std::iter::repeat_n(200.0f32, 300));
        values.push(f32::NAN);
        let t = otsu_threshold(&values).expect("two values");
        assert!(t > 10.0 && t < 200.0, "threshold {t}");
        assert_eq!(foreground(&values, t).len(), 300);
        assert!(otsu_threshold(&[3.0, 3.0]).is_none());
    }

    /// A 24³ volume of 2 mm voxels holding a bright ball of radius 7 voxels about the centre.
    fn ball() -> (Volume, Vec<f32>) {
        use warpbench_io::geometry::Transform;
        use warpbench_io::volume::{GeometrySource, VoxelData};
        let n = 24;
        let values: Vec<f32> = (0..n * n * n)
            .map(|i| {
                let c = ijk([n; 3], i).map(|x| x as f64 - 11.5);
                if dist(c, [0.0; 3]) < 7.0 { 100.0 } else { 5.0 }
            })
            .collect();
        let lps_from_index = Transform::from_scale_translation([2.0; 3], [-10.0, 4.0, 30.0]);
        let v = Volume::new(
            std::path::Path::new("ball"),
            [n; 3],
            VoxelData::F32(values.clone()),
            lps_from_index,
            GeometrySource::Assumed,
        )
        .expect("valid volume");
        (v, values)
    }

    #[test]
    fn random_points_are_distinct_foreground_voxels_jittered_inside() {
        let (v, values) = ball();
        let fg = foreground(&values, otsu_threshold(&values).expect("two values"));
        let points = random_points(&v, &fg, 200, &mut SplitMix64::new(3, 0), |_| true);
        assert_eq!(points.len(), 200);
        let index_from_lps = v.lps_from_index.inverse().expect("invertible");
        let mut voxels: Vec<usize> = points
            .iter()
            .map(|p| {
                let idx = index_from_lps.apply_point(Point3::from_array(*p)).coords();
                let [i, j, k] = idx.map(|c| c.round() as usize);
                assert!(idx.iter().all(|c| (c - c.round()).abs() <= 0.5), "{idx:?}");
                i + v.dims[0] * (j + v.dims[1] * k)
            })
            .collect();
        assert!(voxels.iter().all(|i| fg.binary_search(i).is_ok()));
        voxels.sort_unstable();
        voxels.dedup();
        assert_eq!(voxels.len(), 200, "voxels repeat");
        // Asking for more than there are gives every voxel once.
        assert_eq!(random_points(&v, &fg, fg.len() + 5, &mut SplitMix64::new(3, 0), |_| true).len(), fg.len());
    }

    #[test]
    fn feature_points_sit_on_edges_spread_apart() {
        let (v, values) = ball();
        let fg = foreground(&values, otsu_threshold(&values).expect("two values"));
        let points = feature_points(&v, &values, &fg, 12, &mut SplitMix64::new(5, 0), |_| true);
        assert_eq!(points.len(), 12);
        let centre = [-10.0 + 2.0 * 11.5, 4.0 + 2.0 * 11.5, 30.0 + 2.0 * 11.5];
        for p in &points {
            // On the ball's boundary layer: within a voxel (2 mm) of the 14 mm radius.
            let r = dist(*p, centre);
            assert!((11.0..=15.5).contains(&r), "{p:?} at {r} mm from the centre");
        }
        let closest = (0..12)
            .flat_map(|a| (a + 1..12).map(move |b| (a, b)))
            .map(|(a, b)| dist(points[a], points[b]))
            .fold(f64::INFINITY, f64::min);
        assert!(closest >= 4.0, "two feature points only {closest} mm apart");
        let again = feature_points(&v, &values, &fg, 12, &mut SplitMix64::new(5, 0), |_| true);
        assert_eq!(points, again);
    }

    #[test]
    fn generator_is_seeded_and_streams_differ() {
        let draw = |seed, stream| {
            let mut g = SplitMix64::new(seed, stream);
            (0..4).map(|_| g.next_u64()).collect::<Vec<_>>()
        };
        assert_eq!(draw(7, 1), draw(7, 1));
        assert_ne!(draw(7, 1), draw(7, 2));
        assert_ne!(draw(7, 1), draw(8, 1));
        let mut g = SplitMix64::new(1, 0);
        assert!((0..1000).all(|_| g.below(7) < 7 && (0.0..1.0).contains(&g.unit())));
    }
}
