//! The samplers' tests: overrides, flat images and edges for every sampler, tile
//! independence and jittered positions; the adaptive sampler's own are in `adaptive`.

use super::adaptive::*;
use super::jitter::*;
use super::*;
use crate::math::Color;
use crate::tile::Rect;

fn flat(color: f64) -> impl Fn(f64, f64) -> Sample {
    move |_, _| Sample {
        color: Color::splat(color),
        object: 0,
    }
}

/// A [`PixelGeometry`] from three closures: `smooth(px, py)`, `hides(px, py, object)` and
/// `step(px, py, object, seen)`.
struct Geo<S, H, C>(S, H, C);

impl<S, H, C> PixelGeometry for Geo<S, H, C>
where
    S: Fn(i64, i64) -> bool,
    H: Fn(i64, i64, u32) -> bool,
    C: Fn(i64, i64, u32, &[(f64, f64)]) -> Option<UnseenPattern>,
{
    fn is_smooth(&self, px: i64, py: i64, _: f64, _: f64, _: &Sample) -> bool {
        (self.0)(px, py)
    }

    fn may_hide(&self, px: i64, py: i64, object: u32) -> bool {
        (self.1)(px, py, object)
    }

    fn unseen_pattern(
        &self,
        px: i64,
        py: i64,
        object: u32,
        seen: &[(f64, f64)],
    ) -> Option<UnseenPattern> {
        (self.2)(px, py, object, seen)
    }

    fn pattern_alone(&self, _: i64, _: i64, _: f64, _: f64, _: u32) -> bool {
        false
    }
}

/// No pattern edge known anywhere.
fn no_crossing(_: i64, _: i64, _: u32, _: &[(f64, f64)]) -> Option<UnseenPattern> {
    None
}

/// A geometry that knows nothing hidden, and smooth pixels by `smooth`.
fn smooth_where(smooth: impl Fn(i64, i64) -> bool) -> impl PixelGeometry {
    Geo(smooth, |_, _, _| false, no_crossing)
}

/// A vertical edge at x = 10.3: white to its left.
fn edge(x: f64, _y: f64) -> Sample {
    let white = x < 10.3;
    Sample {
        color: Color::splat(if white { 1.0 } else { 0.0 }),
        object: u32::from(white),
    }
}

const ALL: [Sampler; 9] = [
    Sampler::Center,
    Sampler::Thesis,
    Sampler::Grid { n: 3 },
    Sampler::Jitter { n: 4 },
    Sampler::Adaptive {
        max: 4,
        threshold: 0.02,
    },
    Sampler::Adaptive {
        max: 6,
        threshold: 0.02,
    },
    Sampler::Adaptive {
        max: 8,
        threshold: 0.02,
    },
    Sampler::Adaptive {
        max: 3,
        threshold: 0.02,
    },
    Sampler::Jitter { n: 1 },
];

#[test]
fn overrides_keep_what_they_do_not_name() {
    let s = Sampler::Adaptive {
        max: 6,
        threshold: 0.1,
    };
    assert_eq!(
        s.with_overrides(None, Some(3), None, 32),
        Ok(Sampler::Adaptive {
            max: 3,
            threshold: 0.1
        })
    );
    assert_eq!(
        s.with_overrides(Some("jitter"), None, None, 32),
        Ok(Sampler::Jitter { n: 6 })
    );
    // Any case, as in a scene.
    assert_eq!(
        s.with_overrides(Some("JITTER"), None, None, 32),
        Ok(Sampler::Jitter { n: 6 })
    );
    assert_eq!(
        Sampler::Center.with_overrides(Some("grid"), None, None, 32),
        Ok(Sampler::Grid { n: 4 })
    );
    assert!(s.with_overrides(None, Some(33), None, 32).is_err());
    assert!(s.with_overrides(None, None, Some(f64::NAN), 32).is_err());
    assert!(s.with_overrides(Some("random"), None, None, 32).is_err());
    // A setting the resulting sampler does not use is refused, whichever side named the
    // sampler; a scene's own unused setting is not the user's doing and is dropped.
    let unused = |r: Result<Sampler, String>, what: &str| {
        let e = r.expect_err("an unused setting");
        assert!(e.starts_with(what), "{e}");
    };
    unused(
        Sampler::Center.with_overrides(None, Some(4), None, 32),
        "samples",
    );
    unused(
        s.with_overrides(Some("thesis"), Some(4), None, 32),
        "samples",
    );
    unused(
        Sampler::Jitter { n: 2 }.with_overrides(None, None, Some(0.1), 32),
        "threshold",
    );
    unused(
        s.with_overrides(Some("grid"), None, Some(0.1), 32),
        "threshold",
    );
    assert_eq!(
        s.with_overrides(Some("center"), None, None, 32),
        Ok(Sampler::Center)
    );
}

#[test]
fn a_flat_image_is_flat_for_every_sampler() {
    for s in ALL {
        let rect = Rect::new(3, 4, 5, 6);
        let mut out = vec![Color::ZERO; rect.pixel_count()];
        s.render_rect(rect, flat(0.25), &mut out);
        assert!(
            out.iter()
                .all(|c| (*c - Color::splat(0.25)).length() < 1e-15),
            "{s:?}"
        );
    }
}

#[test]
fn an_edge_is_estimated_by_its_covered_fraction() {
    // Pixel 10 is 30 % white; the grid of 10 × 10 puts 3 columns of samples left of 10.3.
    let mut out = vec![Color::ZERO; 1];
    Sampler::Grid { n: 10 }.render_rect(Rect::new(10, 0, 1, 1), edge, &mut out);
    assert!((out[0].x - 0.3).abs() < 1e-12);
    Sampler::Jitter { n: 16 }.render_rect(Rect::new(10, 0, 1, 1), edge, &mut out);
    assert!((out[0].x - 0.3).abs() <= 1.0 / 16.0, "{}", out[0].x);
}

#[test]
fn pixel_values_do_not_depend_on_the_tile() {
    for s in ALL {
        let whole = Rect::new(0, 0, 20, 5);
        let mut a = vec![Color::ZERO; whole.pixel_count()];
        s.render_rect(whole, edge, &mut a);
        for x in 0..20 {
            for y in 0..5 {
                let mut one = vec![Color::ZERO; 1];
                s.render_rect(Rect::new(x, y, 1, 1), edge, &mut one);
                assert_eq!(one[0], a[(y * 20 + x) as usize], "{s:?} at ({x}, {y})");
            }
        }
    }
}

#[test]
fn jittered_positions_stay_in_their_cells_and_vary() {
    let mut seen = Vec::new();
    for k in 0..64 {
        let (a, b) = unit_pair(7, 9, k, SEED_JITTER);
        assert!((0.0..1.0).contains(&a) && (0.0..1.0).contains(&b));
        seen.push(a);
    }
    let mean = seen.iter().sum::<f64>() / seen.len() as f64;
    assert!((mean - 0.5).abs() < 0.15, "mean {mean}");
    assert_ne!(
        unit_pair(7, 9, 0, SEED_JITTER),
        unit_pair(9, 7, 0, SEED_JITTER)
    );
}

mod adaptive;
