//! Which lights nothing can hide from an object: found once per scene, so that shading skips
//! the shadow rays whose answer is already known.
//!
//! **What it is for.** A shadow ray from a point of object `o` to light `l` can only be
//! blocked by a solid that meets the segment between them. Every such segment lies in the
//! convex hull of `o`'s box and the light, and so in the *capsule* of radius `r` around the
//! segment from the box's centre `c` to the light, `r` being half the box's diagonal: a point
//! `q + s·(L − q)` of a segment from `q` (with `|q − c| ≤ r`) is `(1 − s)·|q − c| ≤ r` from
//! the point `c + s·(L − c)`. A bounded solid can meet that capsule only if the segment `c → L`
//! enters the solid's box grown by `r` on every side (the box grown by a ball of radius `r`
//! lies inside it). A plane can meet it only if the light and some corner of `o`'s box are
//! not strictly on the same side of it. When no solid but `o`'s own prim passes these tests,
//! every shadow ray from `o` to `l` finds the light clear, and [`ClearLights`] says so.
//!
//! The boxes are those the renderer's BVH uses: a long cylinder or cone is the slices it is
//! cut into (see [`Object::pieces`]), each with its own ball, which keeps a rod's capsules
//! thin; a sphere placed by a similarity is its own ball, and as a blocker must also come
//! within `r` of the segment. A sliced object also keeps each slice's clear lights, which a
//! hit reads by its object-space height ([`ClearLights::mask_at`]): in a fan of rods the
//! slices where two rods pass close are not clear, and the rest of each rod still is.
//!
//! Every test errs towards "may block": boxes are the BVH's padded ones (their slack,
//! 1e-7 of their size, dwarfs both the offset of a shadow ray's origin from the surface and
//! the slab test's rounding), the radius is rounded up, and the plane test keeps a margin of
//! 1e-9 of the coordinates involved. A skipped shadow ray is therefore one that would have
//! returned "not blocked": images are the same, bit for bit, with or without this (see
//! [`crate::world::Scene::without_shadow_culling`] and the tests that use it).
//!
//! **What it is not.** It decides nothing about `o` shadowing itself: the renderer only uses
//! it where the shadow ray would skip `o` anyway (a convex object left from outside). It
//! knows only the first 64 lights (the rest always trace), and it gives up, leaving shadow
//! rays in place, on scenes with unbounded solids other than planes or when its work budget
//! ([`BUDGET`]) runs out.

use std::cell::Cell;
use std::ops::Range;

use glam::DVec3;

use crate::bvh::{self, Bvh};
use crate::csg::Prim;
use crate::math::{Aabb, Ray};
use crate::object::Object;
use crate::scene::Light;
use crate::shape::Shape;

/// Most box and item tests one scene spends on this; past it, the objects not yet decided
/// keep all their shadow rays. It bounds the build time of adversarial scenes (thousands of
/// overlapping objects under many lights) at a few tens of milliseconds.
pub const BUDGET: u64 = 1 << 22;

/// Per object, a bit per light (bit `l` for light `l < 64`): set when no prim other than
/// the object's own can block a shadow ray from the object to that light. For a long
/// cylinder or cone, also a mask per slice (see [`Object::pieces`]): a light that some slice's
/// shadow rays may find blocked is often clear from the others.
#[derive(Debug, Clone, Default)]
pub struct ClearLights {
    masks: Vec<u64>,
    /// Per object, where its slices' masks start in `slice_masks`: empty when no object is
    /// sliced, `u32::MAX` for an object that is not.
    slice_start: Vec<u32>,
    /// Per sliced object, its number of slices `k`, then `k` masks, the slice of the lowest
    /// object-space `y` first.
    slice_masks: Vec<u64>,
}

impl ClearLights {
    /// The clear lights of every object of a scene. `tree` is the scene's BVH if it has one
    /// (items named by prim index, a long object once per slice, as
    /// [`crate::world::Scene`] builds it); without it, one is built here.
    pub fn find(
        objects: &[Object],
        prims: &[Prim],
        lights: &[Light],
        tree: Option<&Bvh>,
    ) -> ClearLights {
        let masks = vec![0u64; objects.len()];
        let mut clear = ClearLights {
            masks,
            ..ClearLights::default()
        };
        let lights = &lights[..lights.len().min(64)];
        if lights.is_empty() {
            return clear;
        }
        // One pass over the prims. Unbounded ones: a plane is kept to test against; anything
        // else (an unbounded CSG tree) may be anywhere, and nothing is culled. Bounded ones:
        // the boxes the renderer's BVH gives them, one, or for a long cylinder or cone the
        // slices it is cut into (tighter both as blockers and as the object whose light is in
        // question). A box that cannot be padded (coordinates near the largest double) would
        // be a blocker left out: then nothing is culled either.
        let mut planes = Vec::new();
        let mut pieces: Vec<Aabb> = Vec::new();
        let mut ranges: Vec<Range<usize>> = Vec::with_capacity(prims.len());
        let mut items: Vec<(u32, Aabb)> = Vec::new();
        for (pi, p) in prims.iter().enumerate() {
            let first = pieces.len();
            match (p, p.bounds(objects)) {
                (Prim::Object(i), None) if matches!(objects[*i as usize].shape, Shape::Plane) => {
                    let t = &objects[*i as usize].transform;
                    let (p0, _) = t.point_to_world(DVec3::ZERO, DVec3::ZERO);
                    planes.push((p0, t.normal_to_world(DVec3::Y)));
                }
                (_, None) => return clear,
                (_, Some(b)) => {
                    let cut = match p {
                        Prim::Object(o) => objects[*o as usize].pieces(),
                        Prim::Csg(_) => Vec::new(),
                    };
                    for x in if cut.is_empty() { vec![b] } else { cut } {
                        let (Some(padded), Ok(id)) = (bvh::padded(&x), u32::try_from(pi)) else {
                            return clear;
                        };
                        pieces.push(padded);
                        if tree.is_none() {
                            items.push((id, x));
                        }
                    }
                }
            }
            ranges.push(first..pieces.len());
        }
        // The renderer's BVH when it has one (its items are these pieces, each named by its
        // prim), else one built the same way.
        let built;
        let tree = match tree {
            Some(t) => t,
            None => {
                built = Bvh::build(&items).0;
                &built
            }
        };
        // Similarity spheres' centres and radii, the radii padded as the boxes are (by
        // [`bvh::SLACK`] of their size and distance from the origin).
        let spheres: Vec<Option<(DVec3, f64)>> = prims
            .iter()
            .map(|p| match p {
                Prim::Object(i) => objects[*i as usize].similarity_sphere().map(|(c, r2)| {
                    let r = r2.sqrt();
                    (c, r + (r + c.abs().max_element()) * bvh::SLACK)
                }),
                Prim::Csg(_) => None,
            })
            .collect();
        let budget = Cell::new(BUDGET);
        // Spends one unit; true once the budget is gone (then everything "may block").
        let spent = || {
            budget.set(budget.get().saturating_sub(1));
            budget.get() == 0
        };
        // Whether some prim other than `pi` may meet a segment from the ball (c, r) to `light`.
        let may_block = |pi: usize, c: DVec3, r: f64, light: DVec3| {
            let inv = Ray::new(c, light - c).inv_dir();
            let meets = |x: &Aabb| {
                let grown = Aabb::new(x.min - DVec3::splat(r), x.max + DVec3::splat(r));
                grown.hit_interval(c, inv, 1.0).is_some()
            };
            tree.any_item(
                |node| spent() || meets(node),
                |other| {
                    let other = other as usize;
                    other != pi
                        && (spent()
                            || pieces[ranges[other].clone()].iter().any(meets)
                                // A sphere must also come within r of the segment itself.
                                && spheres[other].is_none_or(|(ci, ri)| {
                                    segment_distance(c, light, ci) <= r + ri
                                }))
                },
            )
        };
        for (pi, prim) in prims.iter().enumerate() {
            let own = &pieces[ranges[pi].clone()];
            let Prim::Object(oi) = prim else {
                continue;
            };
            if own.is_empty() {
                continue;
            }
            // The balls about the object: its own sphere when it is one, else one per box.
            let balls: Vec<(DVec3, f64)> = match spheres[pi] {
                Some(ball) => vec![ball],
                None => own
                    .iter()
                    .map(|x| (x.centroid(), 0.5 * (x.max - x.min).length() * (1.0 + 1e-9)))
                    .collect(),
            };
            // Per ball (one per slice for a sliced object), the lights clear from it.
            let ball_masks: Vec<u64> = balls
                .iter()
                .zip(own)
                .map(|(&(c, r), x)| {
                    let mut mask = 0u64;
                    for (l, light) in lights.iter().enumerate() {
                        let blocked = planes
                            .iter()
                            .any(|&(p0, n)| plane_may_block(p0, n, x, light.position))
                            || may_block(pi, c, r, light.position);
                        if !blocked {
                            mask |= 1 << l;
                        }
                    }
                    mask
                })
                .collect();
            let oi = *oi as usize;
            clear.masks[oi] = ball_masks.iter().fold(u64::MAX, |a, &m| a & m);
            // Slices worth keeping: some light clear from a slice but not from the whole.
            if ball_masks.len() > 1 && ball_masks.iter().any(|&m| m != clear.masks[oi]) {
                if clear.slice_start.is_empty() {
                    clear.slice_start = vec![u32::MAX; objects.len()];
                }
                // Slices are at most `MAX_PIECES` per object, so the masks of every object
                // of a scene that fits in memory index with u32; past that, no slice masks.
                if let Ok(start) = u32::try_from(clear.slice_masks.len()) {
                    clear.slice_start[oi] = start;
                    clear.slice_masks.push(ball_masks.len() as u64);
                    clear.slice_masks.extend(ball_masks);
                }
            }
        }
        clear
    }

    /// The clear lights of `object`, bit `l` for light `l`.
    #[inline]
    pub fn mask(&self, object: u32) -> u64 {
        self.masks.get(object as usize).copied().unwrap_or(0)
    }

    /// The clear lights of `object` at the point of object-space height `y` on it: its
    /// slice's when it is a sliced cylinder or cone (slice `j` of `k` spans `y` from
    /// `−1 + 2j/k` to `−1 + 2(j + 1)/k`), else [`Self::mask`]. A point within rounding of
    /// a boundary between two slices lies in both slices' padded boxes, so either slice
    /// answers for it; `y` just past the ends (on the caps, by rounding) takes the end
    /// slice. A `y` that no point of the object has (NaN, or far past an end) gets the
    /// whole object's mask.
    #[inline]
    pub fn mask_at(&self, object: u32, y: f64) -> u64 {
        let start = match self.slice_start.get(object as usize) {
            Some(&s) if s != u32::MAX && (-1.5..=1.5).contains(&y) => s as usize,
            _ => return self.mask(object),
        };
        let k = self.slice_masks[start];
        // `(y + 1)/2` lies in [−0.25, 1.25]: `as u64` takes a negative value to slice 0.
        let j = (((y + 1.0) * 0.5 * k as f64) as u64).min(k - 1);
        self.slice_masks[start + 1 + j as usize]
    }

    /// Whether nothing but `object` itself can block its shadow rays to light `light`.
    #[cfg(test)]
    pub fn is_clear(&self, object: u32, light: usize) -> bool {
        light < 64 && self.mask(object) >> light & 1 == 1
    }
}

/// The distance from `p` to the segment from `a` to `b`.
fn segment_distance(a: DVec3, b: DVec3, p: DVec3) -> f64 {
    let d = b - a;
    let dd = d.dot(d);
    let s = if dd > 0.0 {
        ((p - a).dot(d) / dd).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a + d * s).distance(p)
}

/// Whether the plane through `p0` with normal `n` may meet a segment from a point of box `b`
/// to `light`: unless the light and all eight corners lie strictly on one side of it, by a
/// margin that covers the rounding of the signed distances.
fn plane_may_block(p0: DVec3, n: DVec3, b: &Aabb, light: DVec3) -> bool {
    let side = |q: DVec3| {
        let d = n.dot(q - p0);
        let margin = 1e-9 * n.length() * (q.abs().max_element() + p0.abs().max_element() + 1.0);
        if d > margin {
            1
        } else if d < -margin {
            -1
        } else {
            0
        }
    };
    let s = side(light);
    s == 0 || b.corners().iter().any(|&q| side(q) != s)
}

#[cfg(test)]
mod tests {
    use crate::world::Scene;
    use crate::{Limits, MemoryAssets, Rect, TextureLimits};

    fn scene(body: &str) -> Scene {
        let src = format!("[GLOBALS]\nwidth = 40\nheight = 30\n[/GLOBALS]\n{body}");
        Scene::from_source(
            &src,
            &Limits::default(),
            &MemoryAssets::new(),
            &TextureLimits::default(),
        )
        .expect("valid scene")
    }

    fn sphere(r: f64, at: (f64, f64, f64)) -> String {
        format!(
            "[OBJECT]\ntype = sphere\nradius = {r}\ntranslate = <{}, {}, {}>\n[/OBJECT]\n",
            at.0, at.1, at.2
        )
    }

    const LIGHT_ABOVE: &str = "[LIGHT]\nposition = <0, 100, 0>\n[/LIGHT]\n";

    /// Sphere 0, of radius 1 at the origin, under a light straight above it; sphere 1, also
    /// of radius 1, halfway up at distance `x` from the axis. The exact shadow volume is a
    /// cone of radius 1 at the bottom narrowing to the light: at height 50 its radius is
    /// about ½, so sphere 1 truly blocks some shadow rays up to x ≈ 1.5. The test used is
    /// looser by design (a capsule of radius 1): it must say "may block" up to x = 2 and may
    /// say "clear" beyond.
    #[test]
    fn a_sphere_is_clear_unless_another_may_stand_in_its_light() {
        for (x, clear) in [(1.2, false), (1.9, false), (2.1, true), (5.0, true)] {
            let s =
                scene(&(sphere(1.0, (0.0, 0.0, 0.0)) + &sphere(1.0, (x, 50.0, 0.0)) + LIGHT_ABOVE));
            assert_eq!(s.light_is_clear(0, 0), clear, "x = {x}");
            // Sphere 1's own light is clear: nothing is above it.
            assert!(s.light_is_clear(1, 0), "x = {x}");
        }
    }

    /// Where sphere 1 does block, the shadow rays are traced and the shadow shows: sphere 0's
    /// top, seen from above, is darker than with sphere 1 moved out of the way, and the image
    /// is the one every shadow ray traced gives.
    #[test]
    fn a_blocking_sphere_still_casts_its_shadow() {
        let cam = "[CAMERA]\neye = <0, 30, 0.01>\nlook_at = <0, 0, 0>\nfov = 6\n[/CAMERA]\n";
        let near = scene(
            &(sphere(1.0, (0.0, 0.0, 0.0)) + &sphere(1.0, (0.3, 50.0, 0.0)) + LIGHT_ABOVE + cam),
        );
        let far = scene(
            &(sphere(1.0, (0.0, 0.0, 0.0)) + &sphere(1.0, (30.0, 50.0, 0.0)) + LIGHT_ABOVE + cam),
        );
        let rect = Rect::full(40, 30);
        let (a, sa) = near.render_rect_stats(rect);
        let (b, sb) = near
            .clone()
            .without_shadow_culling()
            .render_rect_stats(rect);
        assert!(a == b && sa == sb);
        let (c, sc) = far.render_rect_stats(rect);
        let centre = (15 * 40 + 20) * 3;
        assert!(a[centre] < c[centre], "{} vs {}", a[centre], c[centre]);
        assert!(sa.shadow > 0 && sc.shadow == 0, "{sa:?} {sc:?}");
    }

    /// A long rod is judged by the slices the BVH cuts it into: lying diagonally in the xy
    /// plane with a sphere beside its upper end, it is clear under a light straight above,
    /// though the ball about its whole box (radius about 5) would take the sphere in; the
    /// capsule of the slice at that end misses it.
    #[test]
    fn a_long_rod_is_judged_slice_by_slice() {
        let rod =
            "[OBJECT]\ntype = cylinder\nscale = <0.1, 5, 0.1>\nrotate = <0, 0, 45>\n[/OBJECT]\n";
        let end = 5.0 * std::f64::consts::FRAC_1_SQRT_2;
        let s = scene(&(rod.to_string() + &sphere(0.5, (-end, end, 2.0)) + LIGHT_ABOVE));
        assert!(s.objects[0].pieces().len() >= 4);
        assert!(s.light_is_clear(0, 0));
        // Just above that end, the sphere is in the way.
        let s = scene(&(rod.to_string() + &sphere(0.5, (-end, end + 2.0, 0.0)) + LIGHT_ABOVE));
        assert!(!s.light_is_clear(0, 0));
    }

    /// A rod whose light one end's slices may find blocked keeps it clear from the others:
    /// lying diagonally under a light straight above, with a sphere over its lower end only,
    /// the whole rod is not clear, its upper slices are, and its lower ones are not. The
    /// shadow rays of the clear slices are skipped, and the image, the sphere's shadow on
    /// the rod included, is the one every shadow ray traced gives.
    #[test]
    fn a_rod_s_slices_have_their_own_clear_lights() {
        let end = 5.0 * std::f64::consts::FRAC_1_SQRT_2;
        // From the front and a little above: the lower end shows below the sphere.
        let cam = "[CAMERA]\neye = <0, 8, 30>\nlook_at = <0, 0, 0>\nfov = 30\n[/CAMERA]\n";
        for shape in ["cylinder", "cone"] {
            let rod = format!(
                "[OBJECT]\ntype = {shape}\nscale = <0.6, 5, 0.6>\nrotate = <0, 0, 45>\n[/OBJECT]\n"
            );
            let s = scene(&(rod + &sphere(1.0, (end, 3.0 - end, 0.0)) + LIGHT_ABOVE + cam));
            let k = s.objects[0].pieces().len();
            assert!(k >= 2, "{shape}: {k} slices");
            assert!(!s.light_is_clear(0, 0), "{shape}");
            // Object-space y runs from −1 (the lower end, under the sphere) to 1.
            assert!(s.clear_lights_at(0, 0.99) & 1 == 1, "{shape}");
            assert!(s.clear_lights_at(0, -0.99) & 1 == 0, "{shape}");
            // A slice's mask holds at least the whole's, at every height.
            let whole = s.clear_lights(0);
            for j in 0..=200 {
                let y = -1.0 + f64::from(j) / 100.0;
                assert_eq!(s.clear_lights_at(0, y) & whole, whole, "{shape}, y = {y}");
            }
            // No slice answers for a height the rod does not have.
            for y in [f64::NAN, -3.0, 3.0] {
                assert_eq!(s.clear_lights_at(0, y), whole, "{shape}, y = {y}");
            }
            let rect = Rect::full(40, 30);
            let (a, sa) = s.render_rect_stats(rect);
            let (b, sb) = s.clone().without_shadow_culling().render_rect_stats(rect);
            assert!(a == b, "{shape}: images differ");
            assert!(sa.shadow < sb.shadow, "{shape}: {sa:?} {sb:?}");
            // The sphere's shadow shows: without shadows the image is another.
            let mut unshadowed = s.clone();
            unshadowed.shadow = 0.0;
            assert!(
                unshadowed.render_rect(rect) != a,
                "{shape}: no shadow in view"
            );
        }
    }

    /// A plane blocks only what it separates from the light.
    #[test]
    fn a_plane_blocks_only_across_itself() {
        let floor = "[OBJECT]\ntype = plane\ntranslate = <0, -2, 0>\n[/OBJECT]\n";
        let above = scene(&(sphere(1.0, (0.0, 0.0, 0.0)) + floor + LIGHT_ABOVE));
        assert!(above.light_is_clear(0, 0));
        let below = "[LIGHT]\nposition = <0, -100, 0>\n[/LIGHT]\n";
        assert!(!scene(&(sphere(1.0, (0.0, 0.0, 0.0)) + floor + below)).light_is_clear(0, 0));
        // Touching the plane: the box reaches it, so it may block.
        let touching = "[OBJECT]\ntype = plane\ntranslate = <0, -1, 0>\n[/OBJECT]\n";
        assert!(
            !scene(&(sphere(1.0, (0.0, 0.0, 0.0)) + touching + LIGHT_ABOVE)).light_is_clear(0, 0)
        );
        // The plane itself is unbounded: its shadow rays are always traced.
        assert!(!above.light_is_clear(1, 0));
    }

    /// Lights past the 64th are never culled; an unbounded CSG tree stops all culling.
    #[test]
    fn limits_of_what_is_known() {
        let mut lights = String::new();
        for i in 0..70 {
            lights += &format!("[LIGHT]\nposition = <{i}, 100, 0>\ncolor = 0.01\n[/LIGHT]\n");
        }
        let s = scene(&(sphere(1.0, (0.0, 0.0, 0.0)) + &lights));
        assert!(s.light_is_clear(0, 63));
        assert!(!s.light_is_clear(0, 64));
        let far_csg = "[CSG]\nop = union\ntranslate = <50, -10, 0>\n[OBJECT]\ntype = plane\n[/OBJECT]\n\
                       [OBJECT]\ntype = sphere\n[/OBJECT]\n[/CSG]\n";
        let s = scene(&(sphere(1.0, (0.0, 0.0, 0.0)) + far_csg + LIGHT_ABOVE));
        assert!(!s.light_is_clear(0, 0));
    }
}
