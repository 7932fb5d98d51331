//! The exact image, or how close we can get to it: what every sampler is measured against.
//!
//! SCENE.md defines a pixel's exact value as the average of the clamped radiance over the
//! pixel's square. Two ways to know it:
//!
//! - **Analytically**, where the scene allows: a flat-coloured disc on a black background
//!   covers each pixel by an area that [`disc_coverage`] computes in closed form. A sphere on
//!   the optical axis projects to exactly such a disc ([`sphere_disc_radius`]).
//! - **By a high-rate stratified estimate** ([`crate::Scene::reference_rect`]): `n × n`
//!   jittered samples, one per cell of an `n × n` grid over the pixel. In a smooth pixel the
//!   error is negligible; in a pixel crossed by an edge of contrast `Δ`, only the ≤ `2n`
//!   cells the edge crosses can err, each by at most `Δ/n²`, so the worst case is `2Δ/n` and,
//!   the cells' errors being independent with variance ≤ `Δ²/(4n⁴)`, the RMS error is at most
//!   `Δ/√(2n³)`: 0.0014·Δ at `n = 64`. That bound is checked against the analytic disc by
//!   `tracer/tests/accuracy.rs`, and its `n^-3/2` convergence too.
//!
//! This module measures; it does not render anything users see.

use glam::DVec2;

/// `∫ √(r² − x²) dx`, the area under a circle's upper half from 0 to `x` (|x| ≤ r).
fn half_disc_integral(x: f64, r: f64) -> f64 {
    let x = x.clamp(-r, r);
    0.5 * (x * (r * r - x * x).max(0.0).sqrt() + r * r * (x / r).clamp(-1.0, 1.0).asin())
}

/// Area of the intersection of the disc of radius `r` centred at `c` with the rectangle
/// `[min.x, max.x] × [min.y, max.y]`, in closed form.
///
/// Along x, the disc's chord is `[cy − h(x), cy + h(x)]` with `h = √(r² − (x − cx)²)`;
/// the covered length is that chord clipped to `[y0, y1]`. Between the x positions where
/// `h` crosses `|y0 − cy|` or `|y1 − cy|`, the clipped length is one of `y1 − y0`, `h − y0'`,
/// `y1' + h` or `2h`, each integrable exactly through `half_disc_integral`.
pub fn disc_coverage(c: DVec2, r: f64, min: DVec2, max: DVec2) -> f64 {
    let (a, b) = ((min.x - c.x).max(-r), (max.x - c.x).min(r));
    let (lo, hi) = (min.y - c.y, max.y - c.y);
    if a >= b || lo >= hi || r <= 0.0 {
        return 0.0;
    }
    let mut cuts = vec![a, b];
    for y in [lo, hi] {
        if y.abs() < r {
            let x = (r * r - y * y).sqrt();
            for c in [-x, x] {
                if c > a && c < b {
                    cuts.push(c);
                }
            }
        }
    }
    cuts.sort_by(f64::total_cmp);
    let h = |x: f64| (r * r - x * x).max(0.0).sqrt();
    let hint = |s: f64, e: f64| half_disc_integral(e, r) - half_disc_integral(s, r);
    let mut area = 0.0;
    for w in cuts.windows(2) {
        let (s, e) = (w[0], w[1]);
        if e <= s {
            continue;
        }
        // Which clip applies is constant between cuts: decide it at the midpoint.
        let hm = h(0.5 * (s + e));
        let top_clipped = hi < hm;
        let bottom_clipped = lo > -hm;
        let len = e - s;
        area += match (top_clipped, bottom_clipped) {
            (true, true) => (hi - lo).max(0.0) * len,
            (true, false) => hi * len + hint(s, e),
            (false, true) => hint(s, e) - lo * len,
            (false, false) => 2.0 * hint(s, e),
        }
        .max(0.0);
    }
    area
}

/// Radius, in pixels, of the disc a sphere of radius `r` at distance `d` from the eye, on the
/// optical axis, projects to in an image `height` pixels high with vertical field of view
/// `fov_degrees`: the silhouette cone has half-angle `asin(r/d)`.
pub fn sphere_disc_radius(r: f64, d: f64, fov_degrees: f64, height: u32) -> f64 {
    let on_plane = (r / d).asin().tan();
    on_plane * f64::from(height) / (2.0 * (fov_degrees.to_radians() * 0.5).tan())
}

/// Root-mean-square and largest absolute differences between two images, over every
/// channel of every pixel, in linear RGB.
pub fn error(a: &[crate::math::Color], b: &[crate::math::Color]) -> (f64, f64) {
    let mut sum = 0.0;
    let mut worst: f64 = 0.0;
    for (p, q) in a.iter().zip(b) {
        let d = (*p - *q).abs();
        sum += d.length_squared();
        worst = worst.max(d.max_element());
    }
    let n = (a.len().min(b.len()) * 3).max(1) as f64;
    ((sum / n).sqrt(), worst)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[allow(clippy::too_many_arguments)]
    fn cov(cx: f64, cy: f64, r: f64, x0: f64, y0: f64, x1: f64, y1: f64) -> f64 {
        disc_coverage(
            DVec2::new(cx, cy),
            r,
            DVec2::new(x0, y0),
            DVec2::new(x1, y1),
        )
    }

    #[test]
    fn coverage_of_simple_configurations() {
        let pi = std::f64::consts::PI;
        // The whole disc inside the rectangle.
        assert!((cov(0.0, 0.0, 1.0, -2.0, -2.0, 2.0, 2.0) - pi).abs() < 1e-14);
        // A quadrant.
        assert!((cov(0.0, 0.0, 1.0, 0.0, 0.0, 5.0, 5.0) - pi / 4.0).abs() < 1e-14);
        // A rectangle inside the disc.
        assert!((cov(0.0, 0.0, 10.0, -1.0, -1.0, 1.0, 1.0) - 4.0).abs() < 1e-14);
        // Disjoint.
        assert_eq!(cov(0.0, 0.0, 1.0, 2.0, 2.0, 3.0, 3.0), 0.0);
        // Half of the disc, cut by a horizontal line through the centre.
        assert!((cov(3.0, 4.0, 2.0, 0.0, 4.0, 10.0, 10.0) - 2.0 * pi).abs() < 1e-13);
    }

    #[test]
    fn coverage_matches_dense_point_counting() {
        // A second method: count points of a fine grid (error ≲ perimeter × spacing).
        let (cx, cy, r) = (0.37, -0.21, 0.83);
        for (x0, y0) in [(-0.5, -0.5), (0.1, 0.2), (-1.1, -0.9), (0.6, -0.8)] {
            let (x1, y1) = (x0 + 1.0, y0 + 1.0);
            let m = 2000;
            let mut inside = 0u32;
            for i in 0..m {
                for j in 0..m {
                    let x = x0 + (f64::from(i) + 0.5) / f64::from(m);
                    let y = y0 + (f64::from(j) + 0.5) / f64::from(m);
                    if (x - cx).powi(2) + (y - cy).powi(2) < r * r {
                        inside += 1;
                    }
                }
            }
            let counted = f64::from(inside) / f64::from(m * m);
            let exact = cov(cx, cy, r, x0, y0, x1, y1);
            assert!((counted - exact).abs() < 2e-3, "{counted} vs {exact}");
        }
    }

    #[test]
    fn coverages_of_a_tiling_sum_to_the_disc() {
        let (cx, cy, r) = (5.3, 4.7, 3.1);
        let mut total = 0.0;
        for i in 0..12 {
            for j in 0..12 {
                let (x, y) = (f64::from(i), f64::from(j));
                total += cov(cx, cy, r, x, y, x + 1.0, y + 1.0);
            }
        }
        assert!(
            (total - std::f64::consts::PI * r * r).abs() < 1e-12,
            "{total}"
        );
    }
}
