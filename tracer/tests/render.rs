//! Rendered pixels against values computed independently: by hand for single pixels, and by
//! the reference tracer in `common` for whole images; and the tile property.

mod common;

use common::{
    RefPlane, RefSphere, Reference, compare_with_reference, scene, scene_with, srgb_byte,
};
use glam::DVec3;
use tessera_tracer::{MemoryAssets, Rect, encode_png, tiles};

/// The centre pixel of a Lambertian sphere lit from the eye: the normal points at the eye and
/// the light, so `L = c · (ambient + 1)`.
#[test]
fn centre_of_a_sphere_lit_from_the_eye() {
    let s = scene(
        "[GLOBALS]\nwidth = 11\nheight = 11\nambient = 0.1\nlight = <0, 0, 100>\n[/GLOBALS]\n\
         [OBJECT]\ntype = sphere\nradius = 10\ncolor1 = 0.5\n[/OBJECT]\n",
    );
    let (linear, _) = s.render_rect_linear(Rect::new(5, 5, 1, 1));
    let expected = 0.5 * (0.1 + 1.0);
    assert!(
        (linear[0] - DVec3::splat(expected)).abs().max_element() < 1e-12,
        "{:?}",
        linear[0]
    );
    let bytes = s.render_rect(Rect::new(5, 5, 1, 1));
    assert_eq!(bytes, vec![srgb_byte(expected); 3]);
}

/// A point light at 45° to the normal contributes cos 45°, scaled by the light's colour, and
/// a second light adds linearly; values above 1 clamp.
#[test]
fn lambert_sums_lights_and_clamps() {
    // The camera looks down at a plane; the centre ray hits the origin.
    let src = "[GLOBALS]\nwidth = 9\nheight = 9\nambient = 0.05\n[/GLOBALS]\n\
               [CAMERA]\neye = <0, 10, 0>\nlook_at = <0, 0, 0>\nup = <0, 0, -1>\n[/CAMERA]\n\
               [LIGHT]\nposition = <10, 10, 0>\ncolor = <0.5, 1, 2>\n[/LIGHT]\n\
               [LIGHT]\nposition = <0, 3, 0>\ncolor = 0.25\n[/LIGHT]\n\
               [OBJECT]\ntype = plane\ncolor1 = <1, 0.5, 0.8>\n[/OBJECT]\n";
    let s = scene(src);
    let (px, _) = s.render_rect_linear(Rect::new(4, 4, 1, 1));
    let cos45 = std::f64::consts::FRAC_1_SQRT_2;
    let light = DVec3::new(0.5, 1.0, 2.0) * cos45 + DVec3::splat(0.25);
    let expected = (DVec3::new(1.0, 0.5, 0.8) * (DVec3::splat(0.05) + light)).min(DVec3::ONE);
    assert!(
        (px[0] - expected).abs().max_element() < 1e-12,
        "{:?} vs {expected:?}",
        px[0]
    );
    assert_eq!(px[0].z, 1.0, "the blue channel clamps");
}

/// Shadowed by a sphere between the point and the light: `V = 1 − shadow`.
#[test]
fn shadow_factor_darkens_by_the_preset_amount() {
    let src = "[GLOBALS]\nwidth = 9\nheight = 9\nambient = 0.1\nshadow = 0.6\n[/GLOBALS]\n\
               [CAMERA]\neye = <0, 10, 10>\nlook_at = <0, 0, 0>\n[/CAMERA]\n\
               [LIGHT]\nposition = <0, 20, 0>\n[/LIGHT]\n\
               [OBJECT]\ntype = plane\ncolor1 = 0.8\n[/OBJECT]\n\
               [OBJECT]\ntype = sphere\nradius = 1\ntranslate = <0, 10, 0>\n[/OBJECT]\n";
    let s = scene(src);
    let (px, stats) = s.render_rect_linear(Rect::new(4, 4, 1, 1));
    // The centre ray hits the origin; the light is straight above (cos = 1), behind the sphere.
    let expected = 0.8 * (0.1 + (1.0 - 0.6));
    assert!((px[0].x - expected).abs() < 1e-12, "{:?}", px[0]);
    assert_eq!(stats.shadow, 1, "one light, one shadow ray");
}

/// A perfect mirror facing the camera shows what is behind the camera; a half mirror mixes.
#[test]
fn mirrors_mix_local_and_reflected_light() {
    let src = "[GLOBALS]\nwidth = 3\nheight = 3\nambient = 0.2\nbackground = <0, 0.5, 1>\n[/GLOBALS]\n\
               [CAMERA]\neye = <0, 5, 0>\nlook_at = <0, 0, 0>\nup = <0, 0, -1>\n[/CAMERA]\n\
               [OBJECT]\ntype = plane\ncolor1 = <1, 0, 0>\nmirror = 0.25\n[/OBJECT]\n";
    let s = scene(src);
    let (px, stats) = s.render_rect_linear(Rect::new(1, 1, 1, 1));
    // No lights: local = c · ambient = (0.2, 0, 0); the mirror ray goes up into the background.
    let expected = DVec3::new(0.2, 0.0, 0.0) * 0.75 + DVec3::new(0.0, 0.5, 1.0) * 0.25;
    assert!(
        (px[0] - expected).abs().max_element() < 1e-12,
        "{:?}",
        px[0]
    );
    assert_eq!((stats.primary, stats.mirror, stats.shadow), (1, 1, 0));
}

/// Two parallel perfect mirrors: with `max_depth = n`, n mirror rays are followed and the last
/// returns black, so a ray between them ends black, whatever n.
#[test]
fn max_depth_bounds_the_mirror_recursion() {
    for depth in [0u32, 1, 3] {
        let src = format!(
            "[GLOBALS]\nwidth = 1\nheight = 1\nmax_depth = {depth}\nbackground = 1\n[/GLOBALS]\n\
             [CAMERA]\neye = <0, 0.5, 0>\nlook_at = <0, 0, 0>\nup = <0, 0, -1>\nfov = 1\n[/CAMERA]\n\
             [OBJECT]\ntype = plane\nmirror = 1\n[/OBJECT]\n\
             [OBJECT]\ntype = plane\nmirror = 1\ntranslate = <0, 1, 0>\n[/OBJECT]\n"
        );
        let (px, stats) = scene(&src).render_rect_linear(Rect::new(0, 0, 1, 1));
        assert_eq!(px[0], DVec3::ZERO, "depth {depth}");
        assert_eq!(stats.mirror, u64::from(depth), "depth {depth}");
    }
}

/// A 1×1 texture gives its decoded colour times `color1`; on a plane, the texture's top-left
/// texel lies at x, z ∈ [0, ½) of each unit square.
#[test]
fn textures_are_read_in_linear_light_and_oriented() {
    // 2×2 texture: top row red, white; bottom row green, blue (P3, sRGB-encoded).
    let mut assets = MemoryAssets::new();
    assets.insert(
        "quad.ppm",
        b"P3\n2 2\n255\n255 0 0  255 255 255\n0 255 0  0 0 255\n".to_vec(),
    );
    assets.insert("grey.ppm", b"P3\n1 1\n255\n188 188 188\n".to_vec());
    let plane_at = |x: f64, z: f64| {
        format!(
            "[GLOBALS]\nwidth = 1\nheight = 1\nambient = 1\n[/GLOBALS]\n\
             [CAMERA]\neye = <{x}, 1, {z}>\nlook_at = <{x}, 0, {z}>\nup = <0, 0, -1>\nfov = 1e-3\n[/CAMERA]\n\
             [OBJECT]\ntype = plane\ntexture = quad.ppm\n[/OBJECT]\n"
        )
    };
    let cases = [
        (0.25, 0.25, DVec3::new(1.0, 0.0, 0.0)),
        (0.75, 0.25, DVec3::ONE),
        (0.25, 0.75, DVec3::new(0.0, 1.0, 0.0)),
        (3.75, -1.25, DVec3::new(0.0, 0.0, 1.0)),
    ];
    for (x, z, expected) in cases {
        let (px, _) =
            scene_with(&plane_at(x, z), &assets).render_rect_linear(Rect::new(0, 0, 1, 1));
        assert!(
            (px[0] - expected).abs().max_element() < 1e-6,
            "({x}, {z}): {:?}",
            px[0]
        );
    }
    let src = "[GLOBALS]\nwidth = 1\nheight = 1\nambient = 1\n[/GLOBALS]\n\
               [OBJECT]\ntype = sphere\nradius = 10\ntexture = grey.ppm\ncolor1 = <1, 0.5, 0>\n[/OBJECT]\n";
    let (px, _) = scene_with(src, &assets).render_rect_linear(Rect::new(0, 0, 1, 1));
    let grey = ((188.0 / 255.0 + 0.055) / 1.055f64).powf(2.4);
    assert!(
        (px[0] - DVec3::new(grey, grey * 0.5, 0.0))
            .abs()
            .max_element()
            < 1e-6
    );
}

/// A missing or broken texture is reported at the position of its name.
#[test]
fn texture_errors_name_the_file_and_position() {
    let src = "[OBJECT]\ntype = sphere\ntexture = nowhere.png\n[/OBJECT]\n";
    let err = tessera_tracer::Scene::from_source(
        src,
        &tessera_tracer::Limits::default(),
        &MemoryAssets::new(),
        &tessera_tracer::TextureLimits::default(),
    )
    .expect_err("missing texture");
    let d = err.first();
    assert_eq!((d.pos.line, d.pos.column), (3, 11));
    assert!(d.message.contains("nowhere.png"), "{}", d.message);
}

/// A scene's textures together stay within `max_total_pixels`: the texture that would pass
/// it is refused at its name, sized from its header; at the limit exactly all load. A texture
/// used twice counts once.
#[test]
fn textures_together_stay_within_their_budget() {
    // Three 4×4 textures, `a` used twice: 48 texels in all.
    let mut assets = MemoryAssets::new();
    for name in ["a.ppm", "b.ppm", "c.ppm"] {
        let mut ppm = b"P6\n4 4\n255\n".to_vec();
        ppm.extend_from_slice(&[128; 48]);
        assets.insert(name, ppm);
    }
    let src = "[OBJECT]\ntype = sphere\ntexture = a.ppm\n[/OBJECT]\n\
               [OBJECT]\ntype = sphere\ntexture = b.ppm\n[/OBJECT]\n\
               [OBJECT]\ntype = sphere\ntexture = a.ppm\n[/OBJECT]\n\
               [OBJECT]\ntype = sphere\ntexture = c.ppm\n[/OBJECT]\n";
    let build = |total: u64| {
        let limits = tessera_tracer::TextureLimits {
            max_total_pixels: total,
            ..tessera_tracer::TextureLimits::default()
        };
        tessera_tracer::Scene::from_source(
            src,
            &tessera_tracer::Limits::default(),
            &assets,
            &limits,
        )
    };
    assert!(build(48).is_ok());
    let err = build(47).expect_err("one texel over");
    assert_eq!(err.diagnostics().len(), 1, "{err}");
    let d = err.first();
    // `c.ppm`, named on line 15, column 11.
    assert_eq!((d.pos.line, d.pos.column), (15, 11), "{}", d.message);
    assert!(
        d.message.contains("`c.ppm` (16 texels)") && d.message.contains("to 48 texels"),
        "{}",
        d.message
    );
}

fn reference_scene() -> (String, Reference) {
    let src = "\
[GLOBALS]
width = 48
height = 36
ambient = <0.1, 0.12, 0.1>
shadow = 0.7
background = <0.2, 0.3, 0.5>
max_depth = 3
[/GLOBALS]
[CAMERA]
eye = <2, 9, 28>
look_at = <0, 1.5, 0>
fov = 40
[/CAMERA]
[LIGHT]
position = <20, 30, 20>
[/LIGHT]
[LIGHT]
position = <-15, 12, 8>
color = <0.4, 0.3, 0.2>
[/LIGHT]
[OBJECT]
type = plane
color1 = 0.9
color2 = <0.1, 0.1, 0.15>
mirror = 0.1
[/OBJECT]
[OBJECT]
type = sphere
radius = 3
translate = <-4, 3, 0>
color1 = <1, 0.8, 0.6>
mirror = 0.6
[/OBJECT]
[OBJECT]
type = sphere
radius = 2
translate = <4, 2, 2>
color1 = <0.2, 0.9, 0.3>
[/OBJECT]
[OBJECT]
type = sphere
radius = 1
translate = <0.5, 6, -3>
color1 = <0.9, 0.2, 0.2>
[/OBJECT]
"
    .to_string();
    let mut r = Reference::new(48, 36);
    r.eye = DVec3::new(2.0, 9.0, 28.0);
    r.look_at = DVec3::new(0.0, 1.5, 0.0);
    r.fov = 40.0;
    r.ambient = DVec3::new(0.1, 0.12, 0.1);
    r.shadow = 0.7;
    r.background = DVec3::new(0.2, 0.3, 0.5);
    r.max_depth = 3;
    r.lights = vec![
        (DVec3::new(20.0, 30.0, 20.0), DVec3::ONE),
        (DVec3::new(-15.0, 12.0, 8.0), DVec3::new(0.4, 0.3, 0.2)),
    ];
    r.plane = Some(RefPlane {
        y: 0.0,
        color1: DVec3::splat(0.9),
        color2: Some(DVec3::new(0.1, 0.1, 0.15)),
        mirror: 0.1,
    });
    r.spheres = vec![
        RefSphere {
            centre: DVec3::new(-4.0, 3.0, 0.0),
            radius: 3.0,
            color: DVec3::new(1.0, 0.8, 0.6),
            mirror: 0.6,
        },
        RefSphere {
            centre: DVec3::new(4.0, 2.0, 2.0),
            radius: 2.0,
            color: DVec3::new(0.2, 0.9, 0.3),
            mirror: 0.0,
        },
        RefSphere {
            centre: DVec3::new(0.5, 6.0, -3.0),
            radius: 1.0,
            color: DVec3::new(0.9, 0.2, 0.2),
            mirror: 0.0,
        },
    ];
    (src, r)
}

/// Every pixel of a scene with a checkered mirror plane, a mirror sphere, shadows and two
/// coloured lights matches the independent reference tracer.
#[test]
fn a_whole_image_matches_the_reference_tracer() {
    let (src, reference) = reference_scene();
    let s = scene(&src);
    let (linear, _) = s.render_rect_linear(Rect::full(48, 36));
    let compared = compare_with_reference(&linear, &reference, false, 1e-9);
    assert!(
        compared > 48 * 36 * 9 / 10,
        "only {compared} pixels compared"
    );
}

/// `antialias = on` averages the thesis's five rays.
#[test]
fn antialias_on_is_the_thesis_five_ray_average() {
    let (src, reference) = reference_scene();
    let src = src.replacen("[GLOBALS]\n", "[GLOBALS]\nantialias = on\n", 1);
    let (linear, stats) = scene(&src).render_rect_linear(Rect::full(48, 36));
    assert_eq!(stats.primary, 5 * 48 * 36);
    let compared = compare_with_reference(&linear, &reference, true, 1e-9);
    assert!(
        compared > 48 * 36 * 8 / 10,
        "only {compared} pixels compared"
    );
}

fn feature_scene(sampler: &str) -> String {
    format!(
        "[GLOBALS]\nwidth = 61\nheight = 43\nbackground = <0.1, 0.2, 0.3>\n{sampler}\n[/GLOBALS]\n\
         [CAMERA]\neye = <3, 6, 20>\nlook_at = <0, 1, 0>\nfov = 45\n[/CAMERA]\n\
         [LIGHT]\nposition = <10, 20, 10>\n[/LIGHT]\n\
         [LIGHT]\nposition = <-10, 5, 5>\ncolor = 0.3\n[/LIGHT]\n\
         [OBJECT]\ntype = plane\ncolor1 = 1\ncolor2 = 0.1\nscale = 2\n[/OBJECT]\n\
         [OBJECT]\ntype = sphere\nradius = 2\ntranslate = <-3, 2, 0>\nmirror = 0.5\n[/OBJECT]\n\
         [OBJECT]\ntype = sphere\nradius = 1.5\nscale = <1, 2, 1>\nrotate = <0, 0, 30>\ntranslate = <3, 3, 0>\ntexture = t.ppm\n[/OBJECT]\n"
    )
}

fn texture_assets() -> MemoryAssets {
    let mut a = MemoryAssets::new();
    let mut ppm = b"P6\n4 4\n255\n".to_vec();
    for i in 0..16u32 {
        ppm.extend_from_slice(&[(i * 16) as u8, (255 - i * 16) as u8, ((i * 37) % 255) as u8]);
    }
    a.insert("t.ppm", ppm);
    a
}

/// The tile property: the same scene rendered whole and assembled from odd-sized tiles gives
/// the same bytes, for every sampler (the adaptive one looks at neighbouring pixels).
#[test]
fn tiles_assemble_into_the_whole_image_byte_for_byte() {
    let samplers = [
        "antialias = off",
        "antialias = on",
        "sampler = grid\nsamples = 2",
        "sampler = jitter\nsamples = 3",
        "sampler = adaptive\nsamples = 3\nthreshold = 0.05",
    ];
    for sampler in samplers {
        let s = scene_with(&feature_scene(sampler), &texture_assets());
        let (w, h) = (s.width, s.height);
        let whole = s.render_rect(Rect::full(w, h));
        for tile in [7u32, 13, 64] {
            let mut assembled = vec![0u8; whole.len()];
            for r in tiles(w, h, tile) {
                let bytes = s.render_rect(r);
                for row in 0..r.height {
                    let src =
                        &bytes[(row * r.width * 3) as usize..((row + 1) * r.width * 3) as usize];
                    let start = (((r.y + row) * w + r.x) * 3) as usize;
                    assembled[start..start + src.len()].copy_from_slice(src);
                }
            }
            assert!(
                assembled == whole,
                "{sampler}: tiles of {tile} differ from the whole"
            );
        }
    }
}

/// The whole-image renderer gives the same PNG whatever its tile size and thread count.
#[test]
fn whole_images_do_not_depend_on_tiles_or_threads() {
    let s = scene_with(
        &feature_scene("sampler = adaptive\nsamples = 2"),
        &texture_assets(),
    );
    let render = |threads: usize, tile: u32| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("a thread pool");
        let (rgb, _) = pool.install(|| s.render_image(tile, |_| {}));
        encode_png(s.width, s.height, &rgb).expect("encode")
    };
    let reference = render(1, 64);
    assert_eq!(render(3, 5), reference);
    assert_eq!(render(2, 17), reference);
}

/// Work a scene does not use is not done: no shadow rays for one convex object, or with
/// `shadow = 0`; no mirror rays without mirrors.
#[test]
fn unused_features_cost_no_rays() {
    let one = "[GLOBALS]\nwidth = 20\nheight = 20\nlight = <0, 50, 100>\n[/GLOBALS]\n\
               [OBJECT]\ntype = sphere\nradius = 20\n[/OBJECT]\n";
    let (_, stats) = scene(one).render_rect_linear(Rect::full(20, 20));
    assert_eq!(
        (stats.shadow, stats.mirror),
        (0, 0),
        "nothing can shadow a lone sphere"
    );
    let two = one.to_string() + "[OBJECT]\ntype = plane\ntranslate = <0, -20, 0>\n[/OBJECT]\n";
    let (_, stats) = scene(&two).render_rect_linear(Rect::full(20, 20));
    assert!(stats.shadow > 0, "a second object can cast shadows");
    let no_shadow = two.replacen("[GLOBALS]\n", "[GLOBALS]\nshadow = 0\n", 1);
    let (_, stats) = scene(&no_shadow).render_rect_linear(Rect::full(20, 20));
    assert_eq!(stats.shadow, 0, "shadow = 0 needs no shadow rays");
}

/// A unit sphere rotated and then scaled to an extreme ellipsoid is the same solid as the
/// scaled sphere without the rotation: both are accepted and render the same pixels.
#[test]
fn a_rotation_before_an_extreme_scale_renders_as_the_scale_alone() {
    let src = |rotate: &str| {
        format!(
            "[GLOBALS]\nwidth = 40\nheight = 30\nambient = 0.1\n[/GLOBALS]\n\
             [CAMERA]\neye = <0, 10, 0>\nlook_at = <0, 0, 0>\nup = <0, 0, -1>\n[/CAMERA]\n\
             [LIGHT]\nposition = <3, 10, 2>\n[/LIGHT]\n\
             [OBJECT]\ntype = sphere\ncolor1 = 0.8\n{rotate}scale = <1e4, 1e-4, 2>\n[/OBJECT]\n"
        )
    };
    let plain = scene(&src(""));
    let rotated = scene(&src("rotate = <10, 20, 30>\n"));
    let all = Rect::new(0, 0, 40, 30);
    let (a, _) = plain.render_rect_linear(all);
    let (b, _) = rotated.render_rect_linear(all);
    let lit = a.iter().filter(|c| c.max_element() > 0.5).count();
    assert!(
        lit > 40,
        "the ellipsoid covers a band of the image: {lit} lit pixels"
    );
    for (i, (x, y)) in a.iter().zip(&b).enumerate() {
        assert!(
            (*x - *y).abs().max_element() < 1e-6,
            "pixel {i}: {x:?} vs {y:?}"
        );
    }
}
