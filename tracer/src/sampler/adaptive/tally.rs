//! What an adaptive pixel's samples say so far: their mean, spread and range, whether they
//! met two objects, and whether a step to a neighbour's went unseen. Not where samples go
//! (`first`) nor when a pixel stops (`refine`).

use crate::math::Color;

use crate::sampler::Sample;

/// The samples an adaptive pixel has taken so far: their sum, sum of squares, range and
/// whether they met more than one object.
#[derive(Clone, Copy)]
pub(in crate::sampler) struct Tally {
    pub(in crate::sampler) sum: Color,
    pub(in crate::sampler) sum_sq: Color,
    pub(in crate::sampler) min: Color,
    pub(in crate::sampler) max: Color,
    pub(in crate::sampler) count: u32,
    pub(in crate::sampler) object: u32,
    pub(in crate::sampler) mixed: bool,
}

impl Tally {
    pub(in crate::sampler) fn new() -> Tally {
        Tally {
            sum: Color::ZERO,
            sum_sq: Color::ZERO,
            min: Color::splat(f64::INFINITY),
            max: Color::splat(f64::NEG_INFINITY),
            count: 0,
            object: 0,
            mixed: false,
        }
    }

    pub(in crate::sampler) fn add(&mut self, s: Sample) {
        if self.count == 0 {
            self.object = s.object;
        } else if s.object != self.object {
            self.mixed = true;
        }
        self.sum += s.color;
        self.sum_sq += s.color * s.color;
        self.min = self.min.min(s.color);
        self.max = self.max.max(s.color);
        self.count += 1;
    }

    /// The tally of one sample.
    pub(in crate::sampler) fn of(s: Sample) -> Tally {
        let mut t = Tally::new();
        t.add(s);
        t
    }

    pub(in crate::sampler) fn mean(&self) -> Color {
        self.sum / f64::from(self.count)
    }

    /// Whether a step between these samples' pixel and `other`'s went unseen by both: in
    /// some channel the two means differ by more than `threshold`, and the two ranges of
    /// samples stay apart by more than `threshold` and by more than [`UNSEEN_GAP`] of that
    /// difference. An unseen step leaves a gap as high as the step itself (each pixel's
    /// samples all on its own side); a smooth gradient leaves a third of the difference on
    /// average (each pixel's samples reach towards the other's), and is no step at all.
    pub(in crate::sampler) fn unseen_step(&self, other: &Tally, threshold: f64) -> bool {
        let (a, b) = (self.mean(), other.mean());
        (0..3).any(|i| {
            let difference = (a[i] - b[i]).abs();
            let gap = (self.min[i] - other.max[i]).max(other.min[i] - self.max[i]);
            difference > threshold && gap > threshold && gap > UNSEEN_GAP * difference
        })
    }

    /// The same samples, each `by` more.
    pub(in crate::sampler) fn shifted(&self, by: Color) -> Tally {
        let n = f64::from(self.count);
        Tally {
            sum: self.sum + by * n,
            sum_sq: self.sum_sq + self.sum * by * 2.0 + by * by * n,
            min: self.min + by,
            max: self.max + by,
            ..*self
        }
    }

    /// Whether the samples disagree: more than `threshold` apart in a channel, or on
    /// different objects.
    pub(in crate::sampler) fn contrast(&self, threshold: f64) -> bool {
        self.mixed || (self.max - self.min).max_element() > threshold
    }

    /// The standard error of the mean, largest over the channels, as if the samples were
    /// independent (stratification makes the true error smaller, so this errs on the side
    /// of more samples).
    pub(in crate::sampler) fn standard_error(&self) -> f64 {
        let n = f64::from(self.count);
        let var = (self.sum_sq - self.sum * self.sum / n) / (n - 1.0);
        (var.max_element().max(0.0) / n).sqrt()
    }
}

/// The part of the difference between two neighbours' means that must lie between their
/// ranges of samples for a step between them to count as unseen ([`super::Ask::Unseen`]). A step
/// that neither saw leaves all of it (less the shading's spread); a linear gradient leaves
/// a third on average, more only where both pixels' first rays fell near their centres.
pub(in crate::sampler) const UNSEEN_GAP: f64 = 0.75;
