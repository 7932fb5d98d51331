//! Rays through one point: a table from direction to the solids a ray in that direction may
//! meet, for the rays that all pass through one known point. Every primary ray leaves the
//! eye, and every shadow ray ends at its light.
//!
//! **What it is for.** In a cloud of many small solids a BVH search does not stay short.
//! A ray crossing a sparse cloud of `n` solids enters about `n^(1/3)` node boxes, whatever
//! the tree. Each visit's outcome is a branch no predictor guesses, and the nodes spill out of
//! the cache. For rays through a fixed point `P`, this table answers from the direction
//! alone, with no tree walk.
//!
//! The directions from `P` are cut into cells on the six faces of a cube around `P`, as in a
//! cube map: a direction `w` lies on the face of its largest component, at
//! `(u, v) = (w_j, w_k) / |w_i|` in `[-1, 1]²`. Each cell lists, nearest first, the solids
//! whose (padded) box some direction of the cell points at. A query looks up its
//! direction's cell and tests that list, where a BVH would walk its tree.
//!
//! This is the light buffer of Haines and Greenberg (1986), applied to the eye as well.
//! The cells of a face cover only the part of the face the boxes cover. There are about two
//! cells per solid there, so a cell of a sparse cloud lists one or two solids.
//!
//! **Why a listed cell is never short of a solid.** A ray can be offered a solid only if the
//! ray passes through the solid's padded box: the BVH drops solids on the same condition (see
//! [`crate::bvh::SLACK`]). If the ray's line passes through `P`, every point `q` of it in the
//! box gives a direction `q − P` inside the box's range of directions. That range is bounded
//! per face from the box corners:
//! - the differences `corner − P` are widened by their rounding;
//! - the quotients are widened by [`PAD`], and then clamped to the face;
//! - a face's window is the union of its footprints, so a direction outside it meets no
//!   listed box;
//! - inside the window, the cell of a coordinate is `(u − u₀)·s` truncated and clamped to the
//!   face's grid. That map is monotone in `u`, so the cells of a range's two ends bound the
//!   cell of every `u` between them.
//!
//! The query's own quotient rounds by an ulp or two, which [`PAD`] covers by nine orders of
//! magnitude.
//!
//! - A **primary ray** starts exactly at the eye, so its direction is the direction of each
//!   of its points.
//! - A **shadow ray** is `o + t·d` with `d = fl(L − o)` and `t < 1 − 10⁻¹⁴`. Its line misses
//!   the light by the rounding `e` of `d`, with `|e| ≤ 2⁻⁵³·|d|`. Seen from `L`, a point of
//!   the segment at distance `s` from `L` lies in the direction `−d` turned by at most
//!   `2⁻⁵³·|d|/s`, which moves a face coordinate by at most four times that. A box nearer
//!   the light than [`NEAR`] of the scene's radius is tested by every query instead of being
//!   listed. The rest are at least `s_min` away, so the lookup is sound while
//!   `|d| ≤ PAD·s_min·2⁵⁰` ([`PointIndex::shadow_lookup_ok`]). That holds for every segment
//!   up to about a hundred times the scene's radius; a longer one takes the BVH.
//!
//! A cell whose list would cost more to test than a tree walk (cost above [`CELL_COST_MAX`])
//! is marked for the BVH, as is every direction with a zero, infinite or NaN component.
//!
//! **What it is not.** It decides nothing about which solid is hit. The caller tests the
//! listed solids exactly as it tests the BVH's candidates, with the same tie rule, so the
//! answers are the same bit for bit (`tests/bvh.rs`). It does not hold unbounded solids
//! (planes), which the caller tests every time. It is not used for rays through any other
//! point (mirror rays), and not for scenes too small to gain ([`MIN_BOXES`]).

use glam::DVec3;

use crate::math::Aabb;

/// Widening of every face coordinate range, in face units (`u, v ∈ [-1, 1]`). It covers the
/// rounding of the query's quotient (about 2⁻⁵² here) and the shadow ray's miss of its
/// light while [`PointIndex::shadow_lookup_ok`] holds.
pub const PAD: f64 = 1e-7;

/// Boxes within this fraction of the scene's radius (the farthest box corner from the point)
/// of the point are tested by every query: seen from so near, a box covers much of the cube,
/// and a shadow ray's rounding turns it too far.
pub const NEAR: f64 = 1e-6;

/// Fewest BVH boxes for which a scene builds tables: the one for its eye, and the ones for
/// its first `MAX_LIGHTS` lights. A long object's slices each count (see
/// `Object::pieces`), since each is a box the BVH search may enter: a fan of sixteen rods
/// cut into a hundred slices walks a tree as deep as a hundred spheres'. With fewer boxes the
/// search is a couple of node visits, and a lookup gains nothing (the cloud bench scenes
/// show it: see PERFORMANCE.md).
pub const MIN_BOXES: usize = 64;

/// Fewest pixels of the image per box to list for which a scene builds tables. A table costs
/// over a thousand instructions a box to build and saves at most about a thousand a ray, some
/// rays of each pixel passing through each point, so a small image over many boxes loses
/// more to building than it gains (a few thousand rods under dozens of lights at 16 × 12
/// render several times as slowly with tables). The threshold is on the safe side: the
/// benchmark's cloud of 16,384 spheres at 160 × 120 (1.2 pixels a box, its tables built with
/// `Acceleration::Always`) already gains from both of its tables; docs/PERFORMANCE.md has
/// the figures.
pub const PIXELS_PER_BOX: u64 = 4;

/// Lights with a table of their own; the others' shadow rays take the BVH.
pub const MAX_LIGHTS: usize = 64;

/// Most cells and entries (solid, cell), eight bytes each, all the tables of one scene may
/// hold together: 32 MB. A table that would hold more than what is left is built coarser,
/// and after a few tries not at all (the BVH serves its rays); once the budget cannot hold a
/// table of every listed solid, no more tables are built. Also at most 2²⁰ cells in
/// one table.
pub const MAX_ENTRIES: usize = 1 << 22;
const MAX_CELLS: usize = 1 << 20;

/// Cells per listed solid on a face, before [`MAX_CELLS`].
const CELLS_PER_SOLID: f64 = 2.0;

/// A cell whose solids cost more than this to test (in the SAH's units: a similarity sphere
/// 1, another object 2, see `world::prim_cost`) takes the BVH instead: some twenty node visits
/// of a deep tree cost about as much as sixteen spheres' quick tests.
pub const CELL_COST_MAX: f64 = 16.0;

/// The range of a direction's largest component that [`PointIndex::lookup`] answers: the rest
/// take the BVH (see `face_of`). 2⁻²⁵⁶ and 2²⁵⁶.
const MIN_COMPONENT: f64 = 1.0 / (1u128 << 127) as f64 / (1u128 << 127) as f64 / 4.0;
const MAX_COMPONENT: f64 = 1.0 / MIN_COMPONENT;

/// A cell marked for the BVH (its `len`).
const FALLBACK: u32 = u32::MAX;

/// One listed solid: the caller's prim index, and a lower bound on the square of its padded
/// box's distance from the point, rounded down to `f32` (lists are sorted by it, nearest
/// first). Eight bytes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Entry {
    pub prim: u32,
    pub near_sq: f32,
}

/// One face's grid: the cells over its window `[u0, u1] × [v0, v1]`, the union of the
/// footprints on the face.
#[derive(Debug, Clone, Copy, Default)]
struct Face {
    u0: f64,
    u1: f64,
    su: f64,
    nu: u32,
    v0: f64,
    v1: f64,
    sv: f64,
    nv: u32,
    /// Index of the face's first cell.
    start: u32,
}

impl Face {
    /// The cell of face coordinates `(u, v)` inside the window: monotone in each (`as`
    /// truncates, which is `floor` for the non-negative offsets from the window's corner, and
    /// saturates), clamped to the grid.
    #[inline]
    fn cell(&self, u: f64, v: f64) -> u32 {
        let cu = (((u - self.u0) * self.su) as u32).min(self.nu - 1);
        let cv = (((v - self.v0) * self.sv) as u32).min(self.nv - 1);
        self.start + cv * self.nu + cu
    }
}

/// The table of one point.
#[derive(Debug, Clone)]
pub struct PointIndex {
    point: DVec3,
    faces: [Face; 6],
    /// Per cell: first entry and count, or `FALLBACK`.
    cells: Vec<(u32, u32)>,
    entries: Vec<Entry>,
    /// Prims with a box within [`NEAR`] of the point, tested by every query.
    always: Vec<u32>,
    /// Square of the longest shadow-ray direction the lookup is sound for.
    shadow_len_sq: f64,
}

/// The face a direction lies on (`2·axis + negative`) and its coordinates there, or `None`
/// for a direction whose largest component is outside `[2⁻²⁵⁶, 2²⁵⁶]` (zero, infinite, NaN,
/// or so small that `1/|w_i|` would overflow, or that squares of lengths along the ray would
/// leave the normal range), or with a NaN anywhere. The coordinates are `w_j · (1/|w_i|)`:
/// two roundings, well inside [`PAD`].
#[inline]
fn face_of(w: DVec3) -> Option<(usize, f64, f64)> {
    let a = w.abs();
    // The axes after `i` in cyclic order: (y, z) on the x faces, (z, x) and (x, y).
    let (face, m, u, v) = if a.x >= a.y && a.x >= a.z {
        (usize::from(w.x < 0.0), a.x, w.y, w.z)
    } else if a.y >= a.z {
        (2 + usize::from(w.y < 0.0), a.y, w.z, w.x)
    } else {
        (4 + usize::from(w.z < 0.0), a.z, w.x, w.y)
    };
    if !(MIN_COMPONENT..=MAX_COMPONENT).contains(&m) {
        return None;
    }
    let inv = 1.0 / m;
    let (u, v) = (u * inv, v * inv);
    // A NaN in another component (with a finite largest one) fails here.
    if u.is_nan() || v.is_nan() {
        return None;
    }
    Some((face, u, v))
}

/// `[lo, hi]` widened to hold the exact difference of two doubles whose rounded difference
/// it is: `fl(a − b)` is within half an ulp of `a − b`, at most `2⁻⁵³·(|a| + |b|)`.
fn widened(lo: f64, hi: f64, scale: f64) -> (f64, f64) {
    let e = scale * f64::EPSILON;
    (lo - e, hi + e)
}

/// The range of `y/x` over `x ∈ [a, b] ∩ (0, ∞)` (with `b > 0`) and `y ∈ [c, d]`,
/// before widening and clamping; infinite ends where `x` reaches 0.
fn quotient_range(a: f64, b: f64, c: f64, d: f64) -> (f64, f64) {
    let lo = if c >= 0.0 {
        c / b
    } else if a > 0.0 {
        c / a
    } else {
        f64::NEG_INFINITY
    };
    let hi = if d <= 0.0 {
        d / b
    } else if a > 0.0 {
        d / a
    } else {
        f64::INFINITY
    };
    (lo, hi)
}

/// One box's footprint on one face, in face coordinates: `[ul, uh] × [vl, vh]`, with what its
/// prim's entries carry: the least `near_sq` over the prim's boxes (already rounded down to
/// `f32`), and what testing the prim costs.
#[derive(Debug, Clone, Copy)]
struct Footprint {
    prim: u32,
    face: usize,
    u: (f64, f64),
    v: (f64, f64),
    near_sq: f32,
    cost: f64,
}

impl PointIndex {
    /// The table of `point` over `items`: each a prim index with one of its padded boxes (in
    /// prim order; a prim may come once per piece) and what testing it costs. `None` when the
    /// table would hold more than `max_entries` cells and entries however coarse, or there is
    /// nothing to list.
    pub fn build(
        point: DVec3,
        items: &[(u32, Aabb, f64)],
        max_entries: usize,
    ) -> Option<PointIndex> {
        if !point.is_finite() || items.is_empty() {
            return None;
        }
        // Each box's exact offset from the point, as a widened interval per axis.
        let offsets: Vec<(DVec3, DVec3)> = items
            .iter()
            .map(|(_, b, _)| {
                let mut lo = DVec3::ZERO;
                let mut hi = DVec3::ZERO;
                for k in 0..3 {
                    let scale = b.min[k].abs().max(b.max[k].abs()) + point[k].abs();
                    (lo[k], hi[k]) = widened(b.min[k] - point[k], b.max[k] - point[k], scale);
                }
                (lo, hi)
            })
            .collect();
        let radius = offsets
            .iter()
            .map(|(lo, hi)| lo.abs().max(hi.abs()).length())
            .fold(0.0, f64::max);
        if !(radius < f64::INFINITY) {
            return None;
        }
        let near = NEAR * radius;
        let mut always: Vec<u32> = Vec::new();
        let mut near_sq = vec![0.0; items.len()];
        for (i, (lo, hi)) in offsets.iter().enumerate() {
            // The nearest point of the box: per axis, the gap to the interval (0 inside).
            let gap = DVec3::ZERO.max(*lo).max(-*hi);
            // Rounded down by far more than the three products' and two sums' rounding.
            near_sq[i] = gap.length_squared() * (1.0 - 1e-12);
            if near_sq[i] < near * near {
                always.push(items[i].0);
            }
        }
        always.dedup();
        // Each box's prim's nearest distance, the least over its pieces (consecutive, since
        // the items come in prim order), as the entries store it.
        let mut prim_near = vec![0.0f32; items.len()];
        let mut start = 0;
        for run in items.chunk_by(|a, b| a.0 == b.0) {
            let end = start + run.len();
            let least = near_sq[start..end]
                .iter()
                .copied()
                .fold(f64::INFINITY, f64::min);
            prim_near[start..end].fill(crate::bvh::round_out(least, false));
            start = end;
        }
        // A prim in `always` is not listed, for any of its pieces.
        let listed = |prim: u32| always.binary_search(&prim).is_err();
        let mut s_min_sq = f64::INFINITY;
        let mut prints: Vec<Footprint> = Vec::new();
        for (i, (lo, hi)) in offsets.iter().enumerate() {
            let prim = items[i].0;
            if !listed(prim) {
                continue;
            }
            s_min_sq = s_min_sq.min(near_sq[i]);
            for face in 0..6 {
                let axis = face / 2;
                let (j, k) = ((axis + 1) % 3, (axis + 2) % 3);
                // Along the face's own axis, pointing out of the face.
                let (a, b) = if face % 2 == 0 {
                    (lo[axis], hi[axis])
                } else {
                    (-hi[axis], -lo[axis])
                };
                if !(b > 0.0) {
                    continue;
                }
                let face_range = |c: f64, d: f64| {
                    let (l, h) = quotient_range(a, b, c, d);
                    ((l - PAD).max(-1.0), (h + PAD).min(1.0))
                };
                let u = face_range(lo[j], hi[j]);
                let v = face_range(lo[k], hi[k]);
                if u.0 <= u.1 && v.0 <= v.1 {
                    prints.push(Footprint {
                        prim,
                        face,
                        u,
                        v,
                        near_sq: prim_near[i],
                        cost: items[i].2,
                    });
                }
            }
        }
        if prints.is_empty() && always.is_empty() {
            return None;
        }
        let mut scale = 1.0;
        for _ in 0..4 {
            if let Some(mut index) = Self::grid(&prints, scale, max_entries) {
                index.point = point;
                index.always = always.clone();
                // See the module comment: a shadow ray's miss of the light, seen from `s`
                // away, turns a face coordinate by at most 4·2⁻⁵³·|d|/s ≤ PAD/2.
                let max_len = PAD * s_min_sq.sqrt() * 2f64.powi(50);
                index.shadow_len_sq = max_len * max_len;
                return Some(index);
            }
            scale *= 0.25;
        }
        None
    }

    /// The grid over `prints` with `scale` times the usual number of cells, or `None` past
    /// the entry budget. Cells whose prims cost more than [`CELL_COST_MAX`] to test are
    /// marked for the BVH.
    fn grid(prints: &[Footprint], scale: f64, max_entries: usize) -> Option<PointIndex> {
        // Each face's window (the union of its footprints) and how many prims it lists.
        let mut window = [(
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ); 6];
        let mut count = [0usize; 6];
        for p in prints {
            let w = &mut window[p.face];
            *w = (
                w.0.min(p.u.0),
                w.1.max(p.u.1),
                w.2.min(p.v.0),
                w.3.max(p.v.1),
            );
            count[p.face] += 1;
        }
        let total: usize = count.iter().sum();
        let budget = (MAX_CELLS as f64).min(CELLS_PER_SOLID * total as f64 * scale);
        // A face without footprints keeps an empty window, which no direction is in.
        let mut faces = [Face {
            u0: f64::INFINITY,
            u1: f64::NEG_INFINITY,
            ..Face::default()
        }; 6];
        let mut cells = 0u32;
        for f in 0..6 {
            if count[f] == 0 {
                continue;
            }
            let (u0, u1, v0, v1) = window[f];
            debug_assert!(u0 <= u1 && v0 <= v1);
            let want = (budget * count[f] as f64 / total as f64).max(1.0);
            // Cells about square in face units, the window's aspect kept.
            let (wu, wv) = ((u1 - u0).max(1e-12), (v1 - v0).max(1e-12));
            let nu = (want * wu / wv).sqrt().round().clamp(1.0, 4096.0);
            let nv = (want / nu).round().clamp(1.0, 4096.0);
            faces[f] = Face {
                u0,
                u1,
                su: nu / wu,
                nu: nu as u32,
                v0,
                v1,
                sv: nv / wv,
                nv: nv as u32,
                start: cells,
            };
            cells += (nu * nv) as u32;
        }
        if cells as usize > max_entries {
            return None;
        }
        // Count, then fill, each prim once per cell however many of its pieces cover it.
        let mut len = vec![0u32; cells as usize];
        let mut stamp = vec![u32::MAX; cells as usize];
        let mut entries = 0usize;
        let each_cell = |p: &Footprint, f: &mut dyn FnMut(usize)| {
            let face = &faces[p.face];
            let (c0, c1) = (face.cell(p.u.0, p.v.0), face.cell(p.u.1, p.v.1));
            let (cu0, cv0) = ((c0 - face.start) % face.nu, (c0 - face.start) / face.nu);
            let (cu1, cv1) = ((c1 - face.start) % face.nu, (c1 - face.start) / face.nu);
            for cv in cv0..=cv1 {
                for cu in cu0..=cu1 {
                    f((face.start + cv * face.nu + cu) as usize);
                }
            }
        };
        for p in prints {
            each_cell(p, &mut |c| {
                if stamp[c] != p.prim {
                    stamp[c] = p.prim;
                    len[c] += 1;
                    entries += 1;
                }
            });
            if cells as usize + entries > max_entries {
                return None;
            }
        }
        let mut starts = Vec::with_capacity(cells as usize);
        let mut at = 0u32;
        for &l in &len {
            starts.push(at);
            at += l;
        }
        let mut out = vec![
            Entry {
                prim: 0,
                near_sq: 0.0,
            };
            entries
        ];
        let mut fill = starts.clone();
        let mut cost = vec![0.0f64; cells as usize];
        stamp.fill(u32::MAX);
        for p in prints {
            each_cell(p, &mut |c| {
                if stamp[c] != p.prim {
                    stamp[c] = p.prim;
                    out[fill[c] as usize] = Entry {
                        prim: p.prim,
                        near_sq: p.near_sq,
                    };
                    fill[c] += 1;
                    cost[c] += p.cost;
                }
            });
        }
        let cells: Vec<(u32, u32)> = starts
            .into_iter()
            .zip(len)
            .zip(cost)
            .map(|((s, l), c)| (s, if c > CELL_COST_MAX { FALLBACK } else { l }))
            .collect();
        for &(s, l) in cells.iter().filter(|c| c.1 != FALLBACK) {
            out[s as usize..(s + l) as usize]
                .sort_unstable_by(|a, b| a.near_sq.total_cmp(&b.near_sq).then(a.prim.cmp(&b.prim)));
        }
        Some(PointIndex {
            point: DVec3::ZERO,
            faces,
            cells,
            entries: out,
            always: Vec::new(),
            shadow_len_sq: 0.0,
        })
    }

    /// The point the table is for.
    pub fn point(&self) -> DVec3 {
        self.point
    }

    /// The prims every query must test besides its cell's (boxes within [`NEAR`] of the
    /// point), in prim order.
    pub fn always(&self) -> &[u32] {
        &self.always
    }

    /// The listed prims a ray through the point in direction `w` (from the point) may meet,
    /// nearest first; `None` where the caller must search its BVH instead.
    #[inline]
    pub fn lookup(&self, w: DVec3) -> Option<&[Entry]> {
        let (f, u, v) = face_of(w)?;
        let face = &self.faces[f];
        // Outside the window no footprint holds the direction (each is widened by `PAD`
        // already); a face without footprints has an empty window.
        if !(u >= face.u0 && u <= face.u1 && v >= face.v0 && v <= face.v1) {
            return Some(&[]);
        }
        let (s, l) = self.cells[face.cell(u, v) as usize];
        if l == FALLBACK {
            return None;
        }
        Some(&self.entries[s as usize..(s + l) as usize])
    }

    /// Whether a shadow ray with direction `d = fl(L − o)` towards this table's light misses
    /// the light by little enough for [`Self::lookup`] of `−d` (see the module comment).
    #[inline]
    pub fn shadow_lookup_ok(&self, d: DVec3) -> bool {
        d.length_squared() <= self.shadow_len_sq
    }

    /// Cells and entries (eight bytes each), for the budget, tests and reports.
    pub fn size(&self) -> (usize, usize) {
        (self.cells.len(), self.entries.len())
    }
}

#[cfg(test)]
mod tests;
