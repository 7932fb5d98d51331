//! The adaptive sampler ends a pixel after one ray only where [`Footprints::is_smooth`]
//! vouches that nothing changes in it but smooth shading, and refines one whose first rays
//! agree wherever [`Footprints::may_hide`] says a sphere or rod may show that they did not
//! see. Both are checked here against brute force:
//! in random scenes (spheres down to a tenth of a pixel, ellipsoids, boxes, rods, tori, CSG
//! trees, tilted planes with horizons, the camera anywhere), every pixel called smooth shows
//! one and the same solid (and checker cell), or the background, at every point of a dense
//! grid over its square, edges and corners included; and every sphere or rod seen at a point
//! of that grid is reported to a first pass that saw anything else.

mod common;

use common::Rng;

use glam::DVec3;
use tessera_tracer::internals::{Coverage, Footprints, PixelRegion, Ray, Sample, SceneInternals};
use tessera_tracer::{Rect, Sampler, Scene, Shape};

fn v(p: DVec3) -> String {
    format!("<{}, {}, {}>", p.x, p.y, p.z)
}

/// A random scene: mostly plain spheres placed by a similarity (the solids a pixel can be
/// smooth on), of every size from a tenth of a pixel up, and among them every other kind of
/// solid, and sometimes a tilted plane. Lights may shadow or not (`shadow = 0`).
fn random_scene(rng: &mut Rng) -> String {
    let mut solids = String::new();
    for _ in 0..rng.below(30) + 5 {
        let at = rng.vec(6.0);
        let c = v(DVec3::new(rng.unit(), rng.unit(), rng.unit()));
        solids += &match rng.below(12) {
            0..=5 => {
                // Radii from 0.005 (a tenth of a pixel at this distance) to 2.
                let r = 0.005 * 400f64.powf(rng.unit());
                format!(
                    "[OBJECT]\ntype = sphere\nradius = {r}\ntranslate = {}\ncolor1 = {c}\n[/OBJECT]\n",
                    v(at)
                )
            }
            6 => {
                let shape = ["cube", "cylinder", "cone", "sphere"][rng.below(4) as usize];
                let s = DVec3::new(
                    rng.range(0.05, 1.0),
                    rng.range(0.5, 4.0),
                    rng.range(0.05, 1.0),
                );
                format!(
                    "[OBJECT]\ntype = {shape}\nscale = {}\nrotate = {}\ntranslate = {}\ncolor1 = {c}\n[/OBJECT]\n",
                    v(s),
                    v(rng.vec(90.0)),
                    v(at)
                )
            }
            7 => format!(
                "[OBJECT]\ntype = torus\nmajor = 1\nminor = 0.2\nrotate = {}\ntranslate = {}\n[/OBJECT]\n",
                v(rng.vec(90.0)),
                v(at)
            ),
            8 => format!(
                "[CSG]\nop = difference\ntranslate = {}\n[OBJECT]\ntype = sphere\n[/OBJECT]\n\
                 [OBJECT]\ntype = cube\nscale = 0.6\ntranslate = <0.5, 0.5, 0.5>\n[/OBJECT]\n[/CSG]\n",
                v(at)
            ),
            // Sub-pixel solids inside a tree: small spheres and a thin rotated torus in a
            // union, which the adaptive sampler must not lose between its first rays.
            10 | 11 => {
                let mut kids = String::new();
                for _ in 0..rng.below(4) + 1 {
                    let r = 0.005 * 40f64.powf(rng.unit());
                    kids += &format!(
                        "[OBJECT]\ntype = sphere\nradius = {r}\ntranslate = {}\n[/OBJECT]\n",
                        v(rng.vec(1.0))
                    );
                }
                kids += &format!(
                    "[OBJECT]\ntype = torus\nmajor = 1\nminor = {}\nscale = <1, 0.5, 1.5>\nrotate = {}\n[/OBJECT]\n",
                    0.005 * 10f64.powf(rng.unit()),
                    v(rng.vec(90.0))
                );
                format!("[CSG]\nop = union\ntranslate = {}\n{kids}[/CSG]\n", v(at))
            }
            _ => {
                let checker = if rng.below(2) == 0 {
                    format!("color2 = 0.1\nscale = {}\n", rng.range(0.2, 3.0))
                } else {
                    String::new()
                };
                format!(
                    "[OBJECT]\ntype = plane\n{checker}rotate = {}\ntranslate = <0, {}, 0>\ncolor1 = {c}\n[/OBJECT]\n",
                    v(rng.vec(40.0)),
                    rng.range(-8.0, -2.0)
                )
            }
        };
    }
    let shadow = if rng.below(2) == 0 {
        "shadow = 0\n"
    } else {
        ""
    };
    format!(
        "[GLOBALS]\nwidth = 48\nheight = 36\nambient = 0.2\n{shadow}[/GLOBALS]\n\
         [CAMERA]\neye = {}\nlook_at = {}\nfov = {}\n[/CAMERA]\n\
         [LIGHT]\nposition = <10, 20, 15>\n[/LIGHT]\n{solids}",
        v(rng.vec(4.0) + DVec3::new(0.0, 0.0, 18.0)),
        v(rng.vec(2.0)),
        rng.range(20.0, 70.0)
    )
}

/// What the primary ray through image position `(x, y)` sees first.
fn seen(s: &Scene, x: f64, y: f64) -> u32 {
    seen_cell(s, x, y).0
}

/// [`seen`], with the checker cell's parity where the object is checkered (as the renderer
/// computes it: the floors of the object's own coordinates, summed).
fn seen_cell(s: &Scene, x: f64, y: f64) -> (u32, i64) {
    let Some(h) = s.intersect(&s.camera().ray(x, y), f64::INFINITY, None) else {
        return (Sample::BACKGROUND, 0);
    };
    let obj = &s.objects()[h.object as usize];
    if obj.material.color2.is_none() {
        return (h.object, 0);
    }
    let p = h.local.p * obj.own_scale;
    let cell = (p.x.floor() as i64) + (p.y.floor() as i64) + (p.z.floor() as i64);
    (h.object, cell & 1)
}

/// The whole image and two pixels beyond it on every side, as a tile's border reaches.
fn past_the_image(s: &Scene) -> PixelRegion {
    PixelRegion {
        x: -2,
        y: -2,
        width: s.width as usize + 4,
        height: s.height as usize + 4,
    }
}

#[test]
fn a_pixel_called_smooth_shows_one_solid_everywhere() {
    let mut rng = Rng(0x5eed_f00d);
    let (mut smooth, mut not, mut on_checker) = (0u32, 0u32, 0u32);
    let mut alone_two_cells = 0u32;
    for case in 0..40 {
        let src = random_scene(&mut rng);
        let s = common::scene(&src);
        let fp = Footprints::new(&s, past_the_image(&s));
        for py in -2..s.height as i64 + 2 {
            for px in -2..s.width as i64 + 2 {
                // A probe anywhere in the pixel.
                let (x, y) = (px as f64 + rng.unit(), py as f64 + rng.unit());
                let (object, cell) = seen_cell(&s, x, y);
                let sample = Sample {
                    color: glam::DVec3::ZERO,
                    object,
                };
                if fp.pattern_alone(px, py, x, y, object) {
                    // Only the cells may change: the same solid at every point.
                    let mut cells = [false; 2];
                    for j in 0..=8 {
                        for i in 0..=8 {
                            let q = (px as f64 + i as f64 / 8.0, py as f64 + j as f64 / 8.0);
                            let (o, c) = seen_cell(&s, q.0, q.1);
                            assert_eq!(
                                o, object,
                                "case {case}, pixel ({px}, {py}) called pattern-alone, but \
                                 ({}, {}) sees another solid\n{src}",
                                q.0, q.1
                            );
                            cells[c as usize] = true;
                        }
                    }
                    alone_two_cells += u32::from(cells[0] && cells[1]);
                } else {
                    assert!(!fp.is_smooth(px, py, x, y, &sample), "smooth but not alone");
                }
                if !fp.is_smooth(px, py, x, y, &sample) {
                    not += 1;
                    continue;
                }
                smooth += 1;
                on_checker += u32::from(
                    s.objects()
                        .get(object as usize)
                        .is_some_and(|o| o.material.color2.is_some()),
                );
                // 9 × 9 points over the square, its edges and corners included.
                for j in 0..=8 {
                    for i in 0..=8 {
                        let (qx, qy) = (px as f64 + i as f64 / 8.0, py as f64 + j as f64 / 8.0);
                        assert_eq!(
                            seen_cell(&s, qx, qy),
                            (object, cell),
                            "case {case}, pixel ({px}, {py}) called smooth, but ({qx}, {qy}) \
                             sees another solid or cell\n{src}"
                        );
                    }
                }
            }
        }
    }
    // Both answers are common, so the check above is not vacuous.
    let total = f64::from(smooth + not);
    assert!(
        f64::from(smooth) > 0.2 * total,
        "{smooth} smooth of {total}"
    );
    assert!(on_checker > 200, "{on_checker} smooth pixels on checkers");
    assert!(
        alone_two_cells > 100,
        "{alone_two_cells} pattern-alone pixels across cells"
    );
    assert!(f64::from(not) > 0.1 * total, "{not} not smooth of {total}");
}

/// The other question the footprints answer: wherever a similarity sphere, a long rod or a
/// torus, alone or in a CSG tree, shows at some point of a pixel's square, [`Footprints::may_hide`] must say it may, to
/// every object but itself, so that a pixel whose first rays all missed it is refined. Same
/// random scenes and grid as above.
#[test]
fn a_sphere_or_rod_that_shows_in_a_pixel_is_never_hidden() {
    let mut rng = Rng(0xd15c_0bed);
    let (mut showing, mut clear, mut flagged_clear) = (0u32, 0u32, 0u32);
    for case in 0..40 {
        let src = random_scene(&mut rng);
        let s = common::scene(&src);
        let fp = Footprints::new(&s, past_the_image(&s));
        // Spheres placed by a similarity, rods (cylinders, cones) and tori, in a tree or
        // not (a tree's child is seen as itself).
        let fitted = |o: u32| {
            s.objects().get(o as usize).is_some_and(|obj| {
                obj.similarity_sphere().is_some()
                    || matches!(
                        obj.shape,
                        Shape::Cylinder | Shape::Cone | Shape::Torus { .. }
                    )
            })
        };
        for py in -2..s.height as i64 + 2 {
            for px in -2..s.width as i64 + 2 {
                let mut seen_here = Vec::new();
                for j in 0..=8 {
                    for i in 0..=8 {
                        let o = seen(&s, px as f64 + i as f64 / 8.0, py as f64 + j as f64 / 8.0);
                        if !seen_here.contains(&o) {
                            seen_here.push(o);
                        }
                    }
                }
                let shown: Vec<u32> = seen_here.iter().copied().filter(|&o| fitted(o)).collect();
                if shown.is_empty() {
                    clear += 1;
                    flagged_clear += u32::from(fp.may_hide(px, py, Sample::BACKGROUND));
                    continue;
                }
                showing += 1;
                // Whatever the first rays saw (the background, or any solid seen here),
                // a fitted solid other than that one shows, and must be reported.
                for &first in seen_here.iter().chain([Sample::BACKGROUND].iter()) {
                    if shown.iter().any(|&o| o != first) {
                        assert!(
                            fp.may_hide(px, py, first),
                            "case {case}, pixel ({px}, {py}): {shown:?} show, but a first \
                             pass that saw only {first} would not be refined\n{src}"
                        );
                    }
                }
            }
        }
    }
    // Not vacuous, and not "everything may hide": few pixels where no fitted solid shows
    // are flagged (those within a pixel's cone of a silhouette; 5 % when written).
    assert!(showing > 2_000, "{showing} pixels show a sphere or rod");
    assert!(
        f64::from(flagged_clear) < 0.15 * f64::from(clear),
        "{flagged_clear} of {clear} clear pixels flagged"
    );
}

/// The quarters a fitted solid may show in: wherever [`Footprints::fitted_quadrants`]
/// answers, every quarter of the square it leaves out shows one and the same thing (the
/// background, or one plane in one checker cell) at every point of a dense grid over it,
/// edges and corners included. Same random scenes as above.
#[test]
fn the_quarters_left_out_show_one_backdrop_alone() {
    let mut rng = Rng(0x0c7a_b1e5);
    let (mut answered, mut partial, mut partial_showing) = (0u32, 0u32, 0u32);
    for case in 0..40 {
        let src = random_scene(&mut rng);
        let s = common::scene(&src);
        let fp = Footprints::new(&s, past_the_image(&s));
        for py in -2..s.height as i64 + 2 {
            for px in -2..s.width as i64 + 2 {
                let Some(bits) = fp.fitted_quadrants(px, py) else {
                    continue;
                };
                answered += 1;
                let mut backdrop = None;
                let mut showing = false;
                for k in 0..4u8 {
                    let (x0, y0) = (
                        px as f64 + 0.5 * f64::from(k & 1),
                        py as f64 + 0.5 * f64::from(k >> 1),
                    );
                    for j in 0..=6 {
                        for i in 0..=6 {
                            let (qx, qy) = (x0 + i as f64 / 12.0, y0 + j as f64 / 12.0);
                            let here = seen_cell(&s, qx, qy);
                            if bits & (1 << k) != 0 {
                                showing |= backdrop.is_some_and(|b| b != here);
                                continue;
                            }
                            let b = *backdrop.get_or_insert(here);
                            assert_eq!(
                                here, b,
                                "case {case}, pixel ({px}, {py}): quarter {k} is left out of \
                                 {bits:04b}, but ({qx}, {qy}) sees something else\n{src}"
                            );
                        }
                    }
                }
                if bits != 0 && bits != 0b1111 {
                    partial += 1;
                    partial_showing += u32::from(showing);
                }
            }
        }
    }
    // Not vacuous: many pixels are answered, and in many of those a solid shows in the
    // quarters named while the others are left out.
    assert!(answered > 5_000, "{answered} pixels answered");
    assert!(
        partial > 250,
        "{partial} pixels with some quarters left out"
    );
    assert!(
        partial_showing > 100,
        "{partial_showing} of them showing a solid"
    );
}

/// Shading that a shadow could change is never smooth: a plane under a sphere and a light is
/// smooth nowhere while its shadow rays are traced, and wherever the horizon and the sphere
/// are out of the pixel once `shadow = 0`.
#[test]
fn surfaces_that_may_be_shadowed_are_never_smooth() {
    let src = "[GLOBALS]\nwidth = 40\nheight = 30\nshadow = 0.8\n[/GLOBALS]\n\
               [CAMERA]\neye = <0, 6, 14>\nlook_at = <0, 0, 0>\n[/CAMERA]\n\
               [LIGHT]\nposition = <4, 20, 6>\n[/LIGHT]\n\
               [OBJECT]\ntype = sphere\nradius = 1.5\ntranslate = <0, 1.5, 0>\n[/OBJECT]\n\
               [OBJECT]\ntype = plane\ncolor1 = 0.8\n[/OBJECT]\n";
    let count = |src: &str| {
        let s = common::scene(src);
        let region = PixelRegion {
            x: 0,
            y: 0,
            width: 40,
            height: 30,
        };
        let fp = Footprints::new(&s, region);
        let plane = 1;
        let mut n = 0;
        for py in 0..30 {
            for px in 0..40 {
                let (x, y) = (px as f64 + 0.5, py as f64 + 0.5);
                let object = seen(&s, x, y);
                let sample = Sample {
                    color: DVec3::ZERO,
                    object,
                };
                n += u32::from(object == plane && fp.is_smooth(px, py, x, y, &sample));
            }
        }
        n
    };
    assert_eq!(count(src), 0, "shadowed plane pixels called smooth");
    let unshadowed = src.replace("shadow = 0.8", "shadow = 0");
    assert!(
        count(&unshadowed) > 300,
        "plain plane pixels should be smooth"
    );
}

/// The third question: wherever a pixel's square shows a checkered plane's other colour
/// at some point of the dense grid while four rays through it all met the plane in one
/// colour, [`Footprints::unseen_pattern`] must name a step and edges, so that the pixel is not
/// ended on the rays' side. Same random scenes; the rays are random points of the square.
#[test]
fn a_checker_colour_the_rays_all_missed_is_never_overlooked() {
    let mut rng = Rng(0xc0ffee);
    let (mut unseen, mut both) = (0u32, 0u32);
    for case in 0..40 {
        let src = random_scene(&mut rng);
        let s = common::scene(&src);
        let fp = Footprints::new(&s, past_the_image(&s));
        for py in -2..s.height as i64 + 2 {
            for px in -2..s.width as i64 + 2 {
                let rays: Vec<(f64, f64)> = (0..4)
                    .map(|_| (px as f64 + rng.unit(), py as f64 + rng.unit()))
                    .collect();
                let seen: Vec<(u32, i64)> =
                    rays.iter().map(|&(x, y)| seen_cell(&s, x, y)).collect();
                let (object, cell) = seen[0];
                let checkered = s
                    .objects()
                    .get(object as usize)
                    .is_some_and(|o| o.material.color2.is_some() && o.shape == Shape::Plane);
                if !checkered || seen.iter().any(|&o| o.0 != object) {
                    continue;
                }
                if seen.iter().any(|&o| o.1 != cell) {
                    both += 1;
                    assert_eq!(fp.unseen_pattern(px, py, object, &rays), None);
                    continue;
                }
                let named = fp.unseen_pattern(px, py, object, &rays);
                let mut other = false;
                for j in 0..=8 {
                    for i in 0..=8 {
                        let q = (px as f64 + i as f64 / 8.0, py as f64 + j as f64 / 8.0);
                        other |= seen_cell(&s, q.0, q.1) == (object, 1 - cell);
                    }
                }
                if other {
                    unseen += 1;
                    assert!(
                        named.is_some_and(|p| p.step > 0.0 && p.edges != Some(0)),
                        "case {case}, pixel ({px}, {py}): the other colour shows, unreported\n{src}"
                    );
                }
            }
        }
    }
    // Each case is common, so the check is not vacuous.
    assert!(
        unseen > 100 && both > 100,
        "{unseen} unseen, {both} seen both"
    );
}

/// [`Scene::checker_step`] bounds what the renderer makes of the two colours: the scene
/// with the colours swapped, traced through every pixel's centre, differs from the scene
/// itself by no more than the step wherever that ray's first hit is the plane. Random planes
/// (turned, tilted, upside down, scaled unevenly, mirroring), one to three lights anywhere,
/// one of them sometimes exactly on the plane, shadows from a sphere, ambient light, the eye
/// on either side. The bound is also not loose everywhere: somewhere it is nearly reached.
#[test]
fn a_checker_s_step_bounds_what_the_renderer_makes_of_its_colours() {
    let mut rng = Rng(0x57e9_ca5e);
    let (mut compared, mut tightest) = (0u32, 0.0f64);
    for case in 0..30 {
        let colour = |rng: &mut Rng| v(DVec3::new(rng.unit(), rng.unit(), rng.unit()));
        let (c1, c2) = (colour(&mut rng), colour(&mut rng));
        let mut lights = String::new();
        for k in 0..rng.below(3) + 1 {
            // The plane passes through the origin before its translation below; a light at
            // y = 0 with no turn lies on it.
            let mut at = rng.vec(8.0);
            if k == 0 && case % 5 == 0 {
                at.y = 0.0;
            }
            lights += &format!(
                "[LIGHT]\nposition = {}\ncolor = {}\n[/LIGHT]\n",
                v(at),
                rng.range(0.2, 1.5)
            );
        }
        let turn = if case % 5 == 0 {
            DVec3::ZERO
        } else {
            rng.vec(180.0)
        };
        let (sx, sz) = (rng.range(0.2, 2.0), rng.range(0.2, 2.0));
        let mirror = if case % 3 == 0 {
            rng.range(0.0, 0.6)
        } else {
            0.0
        };
        let diffuse = rng.range(0.0, 1.5);
        // The same plane twice, only the colours swapped.
        let plane = |a: &str, b: &str| {
            format!(
                "[OBJECT]\ntype = plane\ncolor1 = {a}\ncolor2 = {b}\nscale = <{sx}, 1, {sz}>\n\
                 rotate = {}\nmirror = {mirror}\ndiffuse = {diffuse}\n[/OBJECT]\n",
                v(turn)
            )
        };
        let (pa, pb) = (plane(&c1, &c2), plane(&c2, &c1));
        let rest = format!(
            "[GLOBALS]\nwidth = 32\nheight = 24\nambient = {}\nshadow = {}\n[/GLOBALS]\n\
             [CAMERA]\neye = {}\nlook_at = {}\nfov = 70\n[/CAMERA]\n{lights}\
             [OBJECT]\ntype = sphere\nradius = 0.7\ntranslate = {}\nmirror = 0.5\n[/OBJECT]\n",
            rng.range(0.0, 0.5),
            rng.unit(),
            v(rng.vec(6.0)),
            v(rng.vec(1.0)),
            v(rng.vec(3.0)),
        );
        let (a, b) = (
            common::scene(&(rest.clone() + &pa)),
            common::scene(&(rest + &pb)),
        );
        let plane_id = a.objects().len() as u32 - 1;
        let step = a.checker_step(&a.objects()[plane_id as usize]);
        assert_eq!(step, b.checker_step(&b.objects()[plane_id as usize]));
        let rect = Rect::full(a.width, a.height);
        let (va, _) = a.render_rect_linear_with(rect, &tessera_tracer::Sampler::Center);
        let (vb, _) = b.render_rect_linear_with(rect, &tessera_tracer::Sampler::Center);
        for (i, (pa, pb)) in va.iter().zip(&vb).enumerate() {
            let (x, y) = (
                (i as u32 % a.width) as f64 + 0.5,
                (i as u32 / a.width) as f64 + 0.5,
            );
            if seen(&a, x, y) != plane_id {
                continue;
            }
            let difference = (pa.min(DVec3::ONE) - pb.min(DVec3::ONE))
                .abs()
                .max_element();
            assert!(
                difference <= step + 1e-12,
                "case {case}, pixel {i}: the colours shade {difference} apart, bound {step}"
            );
            compared += 1;
            if step > 0.0 {
                tightest = tightest.max(difference / step);
            }
        }
    }
    assert!(compared > 2000, "{compared} pixels on the planes");
    assert!(
        tightest > 0.9,
        "the bound is never nearly reached: {tightest}"
    );
}

/// A checker too faint to exceed the threshold anywhere (its colours 1e-4 apart, shading
/// at most 1.2) is not searched for a step that could not matter: it costs about what the
/// same plane costs plain (more only because a pixel crossing its cells cannot end after
/// one ray, as on any checker), a small part of what a visible checker costs. (The first
/// form of the rule took every ray there: 3.0 → 581 rays per pixel at a cap of 32.)
#[test]
fn a_checker_fainter_than_the_threshold_costs_nothing() {
    let src = |color2: &str| {
        format!(
            "[GLOBALS]\nwidth = 40\nheight = 30\nambient = 0.2\nsampler = adaptive\nsamples = 16\n\
             threshold = 0.02\n[/GLOBALS]\n[CAMERA]\neye = <0, 3, 8>\n[/CAMERA]\n\
             [LIGHT]\nposition = <2, 10, 5>\n[/LIGHT]\n\
             [OBJECT]\ntype = plane\ncolor1 = 0.5\n{color2}scale = 0.3\nrotate = <0, 30, 0>\n[/OBJECT]\n"
        )
    };
    // The ray rules alone: with the cells' areas, the visible checker takes no more rays.
    let rays = |src: &str| {
        let s = common::scene(src).without_cell_areas();
        s.render_rect_stats(Rect::full(s.width, s.height)).1.primary
    };
    let (faint, visible) = (
        rays(&src("color2 = 0.5001\n")),
        rays(&src("color2 = 0.1\n")),
    );
    let plain = rays(&src(""));
    assert!(
        faint as f64 <= 2.0 * plain as f64 && visible as f64 > 8.0 * faint as f64,
        "faint checker {faint} primary rays, plain plane {plain}, visible checker {visible}"
    );
}

/// A checker whose step barely exceeds the threshold is searched only as far as its bound
/// needs: its colours 0.02 apart under ambient 0.1 and one light (a step of at most 0.022),
/// threshold 0.02, a cap of 32. The first pass (a 2 × 2 stratified set) bounds one edge
/// (0.022 · 3/4 ≤ 0.02), sixteen rays (4 × 4) two (0.022 · 2 · 7/16 ≤ 0.02); with no horizon
/// in view no pixel holds more, so no pixel needs more than 16 rays for the pattern. Nothing
/// but the cells changes on this plane (no shadow can fall on it), so a step between two
/// neighbours that neither saw is a cell edge too, and the same bound decides: it does not
/// send both to every ray (taking every ray wherever the first pass did not bound the edges
/// would cost many times the rays per pixel of the bound).
#[test]
fn a_checker_just_above_the_threshold_is_searched_only_as_far_as_its_bound() {
    // The ray rules alone (with the cells' areas no pixel here searches by rays).
    let rays_per_pixel = |color2: f64| {
        let s = common::scene(&format!(
            "[GLOBALS]\nwidth = 48\nheight = 36\nambient = 0.1\nsampler = adaptive\n\
             samples = 32\nthreshold = 0.02\n[/GLOBALS]\n\
             [CAMERA]\neye = <0, 6, 4>\nfov = 45\n[/CAMERA]\n\
             [LIGHT]\nposition = <3, 10, 5>\n[/LIGHT]\n\
             [OBJECT]\ntype = plane\ncolor1 = 0.5\ncolor2 = {color2}\nscale = 0.4\n\
             rotate = <0, 30, 0>\n[/OBJECT]\n"
        ))
        .without_cell_areas();
        let rays = s.render_rect_stats(Rect::full(s.width, s.height)).1.primary;
        rays as f64 / f64::from(s.width * s.height)
    };
    let (barely, strong) = (rays_per_pixel(0.52), rays_per_pixel(0.58));
    // Not vacuous: a step four times larger sends the crossing pixels further.
    assert!(
        barely <= 16.0 && strong > 2.0 * barely,
        "{barely} rays per pixel, {strong} with a step four times larger"
    );
}

/// In a scene of plain spheres on the background, the adaptive sampler ends most pixels
/// after one ray (or none, where the pixel is blank), and its image assembles from tiles
/// byte for byte, at caps of 4 (refined in one step) and 8 (in stages).
#[test]
fn plain_scenes_take_one_ray_in_flat_pixels_and_stay_tile_independent() {
    for cap in [4, 8] {
        plain_scene_at(cap);
    }
}

fn plain_scene_at(cap: u32) {
    let mut rng = Rng(7);
    let mut spheres = String::new();
    for _ in 0..12 {
        spheres += &format!(
            "[OBJECT]\ntype = sphere\nradius = {}\ntranslate = {}\ncolor1 = <0.9, 0.5, 0.2>\n[/OBJECT]\n",
            rng.range(0.05, 0.8),
            v(rng.vec(5.0))
        );
    }
    let src = format!(
        "[GLOBALS]\nwidth = 50\nheight = 40\nshadow = 0\nsampler = adaptive\nsamples = {cap}\nthreshold = 0.05\n[/GLOBALS]\n\
         [CAMERA]\neye = <0, 0, 20>\n[/CAMERA]\n[LIGHT]\nposition = <5, 10, 20>\n[/LIGHT]\n{spheres}"
    );
    let s = common::scene(&src);
    let (w, h) = (s.width, s.height);
    let whole = s.render_rect_stats(Rect::full(w, h)).0;
    let counts = s.primary_rays_per_pixel(Rect::full(w, h), &s.sampler);
    // Without the smoothness test every pixel would take at least its four-ray first pass.
    let ones = counts.iter().filter(|&&c| c <= 1).count();
    assert!(
        2 * ones > counts.len(),
        "cap {cap}: {ones} of {} pixels end after one ray or none",
        counts.len()
    );
    for tile in [3u32, 8, 19] {
        let mut assembled = vec![0u8; whole.len()];
        for r in tessera_tracer::tiles(w, h, tile) {
            let bytes = s.render_rect(r);
            for row in 0..r.height {
                let src = &bytes[(row * r.width * 3) as usize..((row + 1) * r.width * 3) as usize];
                let start = (((r.y + row) * w + r.x) * 3) as usize;
                assembled[start..start + src.len()].copy_from_slice(src);
            }
        }
        assert!(
            assembled == whole,
            "cap {cap}: tiles of {tile} differ from the whole"
        );
    }
}

/// The footprints are computed per tile (with a border), and a tree's children are found
/// through its index by the tile's region: the adaptive image must still not depend on the
/// tiling. Random scenes of every solid (unions of sub-pixel spheres and thin tori among
/// them), tiles of 7 and 16 against the whole image, byte for byte.
#[test]
fn adaptive_images_of_every_solid_stay_tile_independent() {
    let mut rng = Rng(0x7113);
    for case in 0..6 {
        let src = random_scene(&mut rng).replacen(
            "[/GLOBALS]",
            "sampler = adaptive\nsamples = 4\nthreshold = 0.05\n[/GLOBALS]",
            1,
        );
        assert_tiles_make_the_whole(&src, &format!("case {case}"));
    }
}

/// Renders `src` whole and in tiles of 7 and 16, and asserts the images equal byte for byte.
fn assert_tiles_make_the_whole(src: &str, label: &str) {
    let s = common::scene(src);
    let (w, h) = (s.width, s.height);
    let whole = s.render_rect(Rect::full(w, h));
    for tile in [7u32, 16] {
        let mut assembled = vec![0u8; whole.len()];
        for r in tessera_tracer::tiles(w, h, tile) {
            let bytes = s.render_rect(r);
            for row in 0..r.height {
                let from = (row * r.width * 3) as usize;
                let start = (((r.y + row) * w + r.x) * 3) as usize;
                assembled[start..start + (r.width * 3) as usize]
                    .copy_from_slice(&bytes[from..from + (r.width * 3) as usize]);
            }
        }
        assert!(assembled == whole, "{label}: tiles of {tile} differ\n{src}");
    }
}

/// Rays corrected by a checkered plane's cells (a mirrored floor, shadows on it) compare
/// with their neighbours' across tile borders: the image must still not depend on the
/// tiling, at every cap whose stages differ.
#[test]
fn corrected_checker_floors_stay_tile_independent() {
    let floor = "[GLOBALS]\nwidth = 45\nheight = 34\nambient = 0.1\nbackground = <0.3, 0.4, 0.6>\n\
         sampler = adaptive\nthreshold = 0.02\nsamples = SAMPLES\n[/GLOBALS]\n\
         [CAMERA]\neye = <0, 3, 9>\nlook_at = <0, 0.5, 0>\nfov = 50\n[/CAMERA]\n\
         [LIGHT]\nposition = <6, 8, 2>\n[/LIGHT]\n\
         [OBJECT]\ntype = plane\ncolor1 = 0.9\ncolor2 = 0.15\nscale = 0.6\nmirror = 0.35\n\
         rotate = <0, 20, 0>\n[/OBJECT]\n\
         [OBJECT]\ntype = sphere\nradius = 1.1\nmirror = 0.8\ntranslate = <-0.8, 1.1, 0>\n[/OBJECT]\n\
         [OBJECT]\ntype = cube\nscale = 0.5\nrotate = <0, 30, 0>\ntranslate = <1.5, 0.5, 1>\n[/OBJECT]\n";
    for samples in ["3", "4", "8"] {
        assert_tiles_make_the_whole(
            &floor.replace("SAMPLES", samples),
            &format!("samples {samples}"),
        );
    }
}

/// The count of rays per pixel that the chart draws: jitter's is `n²` in every pixel; an
/// adaptive render's counts lie between none and its cap's `n²`, sum to no more than the
/// render's own count of primary rays (which also holds the rays traced around the rect for
/// its decisions), and show both extremes where a sphere's edge crosses a flat background:
/// none in the background's pixels far from it (blank: nothing can show there), every ray
/// on its edge.
#[test]
fn rays_per_pixel_are_counted_where_they_fall() {
    let s = common::scene(
        "[GLOBALS]\nwidth = 40\nheight = 30\n[/GLOBALS]\n[CAMERA]\neye = <0, 0, 10>\n\
         look_at = <0, 0, 0>\n[/CAMERA]\n[LIGHT]\nposition = <5, 5, 10>\n[/LIGHT]\n\
         [OBJECT]\ntype = sphere\nradius = 1.5\n[/OBJECT]\n",
    );
    let rect = Rect::new(3, 2, 30, 25);
    let counts = s.primary_rays_per_pixel(rect, &Sampler::Jitter { n: 3 });
    assert_eq!(counts.len(), rect.pixel_count());
    assert!(counts.iter().all(|&c| c == 9));

    let adaptive = Sampler::Adaptive {
        max: 4,
        threshold: 0.001,
    };
    let counts = s.primary_rays_per_pixel(rect, &adaptive);
    let (_, stats) = s.render_rect_linear_with(rect, &adaptive);
    let sum: u64 = counts.iter().map(|&c| u64::from(c)).sum();
    assert!(
        sum <= stats.primary,
        "{sum} counted, {} traced",
        stats.primary
    );
    assert!(counts.iter().all(|&c| c <= 16));
    assert_eq!(counts[0], 0, "a background pixel far from the sphere");
    assert!(counts.contains(&16), "the sphere's edge");
}

/// Where [`Footprints::coverage`] answers, the pixel's square shows its solid and the
/// background alone (at every point of a 9 × 9 grid over it), and its share is the area in
/// which the renderer's rays meet the solid: measured over 128 rows, each row's chord found
/// by bisection on the renderer's own hits (the outline is convex, so a row meets it in one
/// interval), within what the rows' spacing allows. Random scenes, the camera anywhere.
#[test]
fn a_covered_pixel_s_share_is_where_its_rays_meet_the_solid() {
    let mut rng = Rng(0xc07e_4a9e);
    let (mut covered, mut measured) = (0u32, 0u32);
    for case in 0..40 {
        let src = random_scene(&mut rng);
        let s = common::scene(&src);
        let fp = Footprints::new(&s, past_the_image(&s));
        for py in -2..s.height as i64 + 2 {
            for px in -2..s.width as i64 + 2 {
                let Some(c) = fp.coverage(px, py) else {
                    continue;
                };
                covered += 1;
                for j in 0..=8 {
                    for i in 0..=8 {
                        let (qx, qy) = (px as f64 + i as f64 / 8.0, py as f64 + j as f64 / 8.0);
                        let o = seen(&s, qx, qy);
                        assert!(
                            o == c.object || o == Sample::BACKGROUND,
                            "case {case}, pixel ({px}, {py}) covered by {}, but ({qx}, {qy}) \
                             sees {o}\n{src}",
                            c.object
                        );
                    }
                }
                if c.share > 0.0 && c.share < 1.0 && measured < 80 {
                    measured += 1;
                    assert_share_by_rows(&s, &c, px, py, &format!("case {case}\n{src}"));
                }
            }
        }
    }
    assert!(covered > 300, "{covered} covered pixels");
    assert!(measured == 80, "{measured} partly covered pixels measured");
}

/// Pixel `(px, py)`'s share `c` is the area its rays meet the solid in, by
/// [`share_by_rows`] over 128 rows, within what the rows' spacing allows.
fn assert_share_by_rows(s: &Scene, c: &Coverage, px: i64, py: i64, label: &str) {
    let by_rows = share_by_rows(s, c.object, px, py, 128);
    assert!(
        (by_rows - c.share).abs() < 2e-3,
        "pixel ({px}, {py}): share {} but {by_rows} by rows ({label})",
        c.share
    );
}

/// The share of pixel `(px, py)`'s square in which the primary rays meet `object`, by the
/// midpoint rule over `rows` rows; each row's chord from 33 points along it, its ends found
/// by bisection between the points that differ.
fn share_by_rows(s: &Scene, object: u32, px: i64, py: i64, rows: u32) -> f64 {
    let n = 32;
    let at = |i: u32| px as f64 + f64::from(i) / f64::from(n);
    let mut area = 0.0;
    for r in 0..rows {
        let y = py as f64 + (f64::from(r) + 0.5) / f64::from(rows);
        let meets = |x: f64| seen(s, x, y) == object;
        // The edge between a point that meets the solid and one that does not.
        let edge = |mut inside: f64, mut outside: f64| {
            for _ in 0..48 {
                let mid = 0.5 * (inside + outside);
                if meets(mid) {
                    inside = mid;
                } else {
                    outside = mid;
                }
            }
            0.5 * (inside + outside)
        };
        let hits: Vec<bool> = (0..=n).map(|i| meets(at(i))).collect();
        let (Some(first), Some(last)) =
            (hits.iter().position(|&h| h), hits.iter().rposition(|&h| h))
        else {
            continue;
        };
        let first = first as u32;
        let last = last as u32;
        let lo = if first == 0 {
            at(0)
        } else {
            edge(at(first), at(first - 1))
        };
        let hi = if last == n {
            at(n)
        } else {
            edge(at(last), at(last + 1))
        };
        area += (hi - lo) / f64::from(rows);
    }
    area
}

/// A fan of rods, from two pixels wide to a twentieth, at every slant, crossing in depth
/// so that some cast shadows on others: where [`Footprints::coverage`] answers for a rod
/// (away from its ends, whose caps have no band for an outline), its share is the area in
/// which the renderer's rays meet it, measured as above, and the square shows the rod and
/// the background alone, with no shadow on the rod at any of 81 points.
#[test]
fn a_rod_s_share_is_where_its_rays_meet_it() {
    let mut rods = String::new();
    for k in 0..12 {
        let r = 0.134 * 0.8f64.powi(k);
        let x = -9.0 + 1.6 * f64::from(k);
        let turn = -35.0 + 6.0 * f64::from(k);
        rods += &format!(
            "[OBJECT]\ntype = cylinder\nradius = {r}\ncolor1 = <0.1, 0.15, 0.3>\n\
             scale = <1, 7, 1>\nrotate = <{}, 0, {turn}>\ntranslate = <{x}, 0, 0>\n[/OBJECT]\n",
            5.0 * f64::from(k)
        );
    }
    // A bar in front of the fan, between it and the light: its shadow crosses the rods.
    rods += "[OBJECT]\ntype = cylinder\nradius = 0.3\nscale = <1, 12, 1>\n\
             rotate = <0, 0, 90>\ntranslate = <0, 2, 3>\n[/OBJECT]\n";
    let src = format!(
        "[GLOBALS]\nwidth = 160\nheight = 120\nambient = 0.15\nbackground = 0.9\n\
         light = <5, 10, 30>\n[/GLOBALS]\n[CAMERA]\neye = <0, 0, 30>\nfov = 30\n[/CAMERA]\n{rods}"
    );
    let s = common::scene(&src);
    let fp = Footprints::new(&s, past_the_image(&s));
    let (mut covered, mut measured, mut lit) = (0u32, 0u32, 0u32);
    for py in 0..s.height as i64 {
        for px in 0..s.width as i64 {
            let Some(c) = fp.coverage(px, py) else {
                continue;
            };
            covered += 1;
            for j in 0..=8 {
                for i in 0..=8 {
                    let (qx, qy) = (px as f64 + i as f64 / 8.0, py as f64 + j as f64 / 8.0);
                    let ray = s.camera().ray(qx, qy);
                    let Some(h) = s.intersect(&ray, f64::INFINITY, None) else {
                        continue;
                    };
                    assert_eq!(h.object, c.object, "pixel ({px}, {py})");
                    // No shadow falls there: the rod's shading is smooth.
                    let p = ray.origin + ray.dir * h.local.t;
                    for light in s.lights() {
                        let to = light.position - p;
                        let shadow = Ray::new(p, to.normalize());
                        assert!(
                            !s.occluded(&shadow, to.length(), Some(c.object)),
                            "pixel ({px}, {py}) covered, but ({qx}, {qy}) is in a shadow"
                        );
                        lit += 1;
                    }
                }
            }
            if c.share > 0.0 && c.share < 1.0 && (px + py) % 5 == 0 {
                measured += 1;
                assert_share_by_rows(&s, &c, px, py, "rods");
            }
        }
    }
    assert!(covered > 500, "{covered} covered pixels");
    assert!(measured > 50, "{measured} partly covered pixels measured");
    assert!(lit > 1000, "{lit} shadow rays checked");
}
