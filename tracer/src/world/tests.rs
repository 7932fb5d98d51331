use super::*;
use crate::diag::SceneError;
use crate::math::{Aabb, Color, Ray};
use crate::object::*;
use crate::scene;
use crate::shape::Shape;
use crate::shape::test_support::Rng;
use crate::tile::Rect;
use crate::transform::Transform;
use crate::{Limits, MemoryAssets, TextureLimits};
use glam::DVec3;

fn build(src: &str) -> Result<Scene, SceneError> {
    Scene::from_source(
        src,
        &Limits::default(),
        &MemoryAssets::new(),
        &TextureLimits::default(),
    )
}

fn scene(src: &str) -> Scene {
    build(src).unwrap_or_else(|e| panic!("test scene does not build: {e}"))
}

fn render(s: &Scene) -> Vec<Color> {
    s.render_rect_linear(Rect::full(s.width, s.height)).0
}

#[test]
fn every_shape_and_key_builds() {
    let s = scene(
        "[OBJECT]\ntype = cube\n[/OBJECT]\n\
             [OBJECT]\ntype = cylinder\nradius = 2\n[/OBJECT]\n\
             [OBJECT]\ntype = cone\n[/OBJECT]\n\
             [OBJECT]\ntype = torus\nmajor = 3\nminor = 0.5\n[/OBJECT]\n\
             [OBJECT]\ntype = torus\n[/OBJECT]\n",
    );
    let shapes: Vec<Shape> = s.objects.iter().map(|o| o.shape).collect();
    assert_eq!(
        shapes,
        [
            Shape::Cube,
            Shape::Cylinder,
            Shape::Cone,
            Shape::Torus {
                major: 3.0,
                minor: 0.5
            },
            Shape::Torus {
                major: 1.0,
                minor: 0.25
            },
        ]
    );
    // A cylinder's radius widens it in x and z only, and sizes its checker cells.
    assert_eq!(s.objects[1].own_scale, DVec3::new(2.0, 1.0, 2.0));
    let b = s.objects[1].bounds.expect("bounded");
    assert_eq!(
        (b.min, b.max),
        (DVec3::new(-2.0, -1.0, -2.0), DVec3::new(2.0, 1.0, 2.0))
    );
    // A torus's radii are its own: no scale, and its box is the ring's.
    assert_eq!(s.objects[3].own_scale, DVec3::ONE);
    let b = s.objects[3].bounds.expect("bounded");
    assert_eq!(b.max, DVec3::new(3.5, 0.5, 3.5));
}

#[test]
fn spindle_and_horn_tori_are_refused_at_the_key() {
    for (keys, line) in [
        ("major = 1\nminor = 1", 3),
        ("major = 1\nminor = 2", 3),
        ("minor = 1.5", 3),
    ] {
        let e = build(&format!("[OBJECT]\ntype = torus\n{keys}\n[/OBJECT]\n"))
            .expect_err("a torus with minor >= major");
        let text = e.to_string();
        assert!(text.contains("minor") && text.contains("major"), "{text}");
        assert!(text.contains(&format!("{line}:")), "{text}");
    }
    let e = build("[OBJECT]\ntype = cube\nmajor = 2\n[/OBJECT]\n").expect_err("no major");
    assert!(e.to_string().contains("does not apply to a cube"), "{e}");
}

#[test]
fn csg_children_compose_with_the_csg_transforms() {
    let s = scene(
        "[CSG]\nop = union\ntranslate = <10, 0, 0>\n\
             [CSG]\nop = union\nscale = 2\n\
             [OBJECT]\ntype = cube\ntranslate = <1, 0, 0>\n[/OBJECT]\n\
             [OBJECT]\ntype = sphere\n[/OBJECT]\n[/CSG]\n\
             [OBJECT]\ntype = cone\n[/OBJECT]\n[/CSG]\n\
             [OBJECT]\ntype = torus\n[/OBJECT]\n",
    );
    assert_eq!(s.objects.len(), 4);
    assert_eq!(s.prims.len(), 2);
    // The cube: own translate, then the inner scale, then the outer translate.
    let c = s.objects[0]
        .transform
        .to_world()
        .transform_point3(DVec3::ZERO);
    assert_eq!(c, DVec3::new(12.0, 0.0, 0.0));
    assert!(s.objects[..3].iter().all(|o| o.in_csg));
    assert!(!s.objects[3].in_csg);
    let b = s.prims[0].bounds(&s.objects).expect("bounded");
    assert_eq!((b.min.x, b.max.x), (8.0, 14.0));
    // Overflowing only once composed: refused at the object, not a panic or NaN.
    // Eleven steps of 1e15 (the largest number a scene may write) are 1e165 on each
    // side, 1e330 composed.
    let big = "scale = 1e15\n".repeat(11);
    let e = build(&format!(
        "[CSG]\nop = union\n{big}\
             [OBJECT]\ntype = cube\n{big}[/OBJECT]\n\
             [OBJECT]\ntype = cube\n[/OBJECT]\n[/CSG]\n",
    ))
    .expect_err("overflowing composite");
    assert!(e.to_string().contains("singular or non-finite"), "{e}");
}

/// `Scene::check` reports exactly what `Scene::build` reports (a composite transform that
/// overflows, of an object and of a nested [CSG], a texture that is missing and one that
/// does not decode, all at once), and accepts what it accepts, without placing objects.
#[test]
fn check_reports_what_build_reports() {
    let desc = |src: &str| scene::parse(src, &Limits::default()).expect("parses");
    let mut assets = MemoryAssets::new();
    assets.insert("bad.ppm", b"P6\n2 2\n255\nxx".to_vec());
    let limits = TextureLimits::default();
    let big = "scale = 1e15\n".repeat(11);
    let bad = desc(&format!(
        "[CSG]\nop = union\n{big}[OBJECT]\ntype = cube\n{big}[/OBJECT]\n\
             [OBJECT]\ntype = cube\n[/OBJECT]\n[/CSG]\n\
             [CSG]\nop = union\n{big}[CSG]\nop = union\n{big}[OBJECT]\ntype = cube\n\
             [/OBJECT]\n[OBJECT]\ntype = cube\n[/OBJECT]\n[/CSG]\n[OBJECT]\ntype = cube\n\
             [/OBJECT]\n[/CSG]\n\
             [OBJECT]\ntype = sphere\ntexture = missing.ppm\n[/OBJECT]\n\
             [OBJECT]\ntype = sphere\ntexture = bad.ppm\n[/OBJECT]\n",
    ));
    let from_build = Scene::build(&bad, &assets, &limits).expect_err("four errors");
    let from_check = Scene::check(&bad, &assets, &limits).expect_err("four errors");
    assert_eq!(from_check.to_string(), from_build.to_string());
    assert_eq!(from_check.diagnostics().len(), 4, "{from_check}");
    assert!(
        from_check.to_string().contains("this [CSG]'s transforms"),
        "{from_check}"
    );
    let good = desc("[OBJECT]\ntype = sphere\n[/OBJECT]\n");
    assert!(Scene::check(&good, &assets, &limits).is_ok());
}

/// The picture: a sphere minus a cube shows the cut face, lit by its own (flat)
/// normal and coloured by the cube. The cube fills z > 0, so the sphere is cut to its
/// back half and the camera on +z looks straight at the disc z = 0. Every pixel inside
/// the disc must equal the exact-image value computed here from the plane z = 0 with
/// normal +z: a sphere normal (or the sphere's colour) would be off by far more.
#[test]
fn sphere_minus_cube_shows_the_cut_face_lit_by_its_own_normal() {
    let s = scene(
        "[GLOBALS]\nwidth = 64\nheight = 64\nambient = 0.1\n[/GLOBALS]\n\
             [CAMERA]\neye = <0, 0, 10>\nfov = 14\n[/CAMERA]\n\
             [LIGHT]\nposition = <3, 4, 10>\n[/LIGHT]\n\
             [CSG]\nop = difference\n\
             [OBJECT]\ntype = sphere\ncolor1 = <0.8, 0.1, 0.1>\n[/OBJECT]\n\
             [OBJECT]\ntype = cube\nscale = 2\ntranslate = <0, 0, 2>\ncolor1 = <0.1, 0.7, 0.2>\n[/OBJECT]\n\
             [/CSG]\n",
    );
    let img = render(&s);
    let green = Color::new(0.1, 0.7, 0.2);
    let light = DVec3::new(3.0, 4.0, 10.0);
    let (mut inside, mut outside) = (0, 0);
    for y in 0..64u32 {
        for x in 0..64u32 {
            let r = s.camera.ray(f64::from(x) + 0.5, f64::from(y) + 0.5);
            let t = -r.origin.z / r.dir.z;
            let p = r.at(t);
            let rho = p.x.hypot(p.y);
            let got = img[(y * 64 + x) as usize];
            if rho < 0.98 {
                let cos = DVec3::Z.dot((light - p).normalize());
                let expect = green * (0.1 + cos);
                assert!(
                    (got - expect).abs().max_element() < 1e-12,
                    "pixel ({x}, {y}): {got:?} vs {expect:?}"
                );
                inside += 1;
            } else if rho > 1.02 {
                assert_eq!(got, Color::ZERO, "pixel ({x}, {y}) outside the disc");
                outside += 1;
            }
        }
    }
    assert!(inside > 1500 && outside > 500, "{inside} {outside}");
}

/// With the only light at the eye, every point the eye sees is lit: the segment back to
/// the light is the one the primary ray came along. So the image must not change when
/// shadows are switched off; a pixel that does is a shadow ray hitting the surface it
/// starts on ("acne"). Tori (which are re-tested by their own shadow rays), CSG surfaces
/// of every kind, coincident faces, transforms and a scene 1e5 from the origin.
#[test]
fn a_light_at_the_eye_casts_no_visible_shadow() {
    let objects = "\
            [OBJECT]\ntype = torus\nmajor = 1.2\nminor = 0.45\nrotate = <60, 10, 0>\nscale = <1, 1.3, 0.8>\ntranslate = <-3, 1.5, 0>\n[/OBJECT]\n\
            [OBJECT]\ntype = torus\nmajor = 1\nminor = 0.02\nrotate = <75, 0, 0>\ntranslate = <3, 1.5, 0>\n[/OBJECT]\n\
            [CSG]\nop = difference\nrotate = <20, 35, 0>\ntranslate = <-3, -1.5, 0>\n\
            [OBJECT]\ntype = sphere\nradius = 1.2\n[/OBJECT]\n\
            [OBJECT]\ntype = cube\ntranslate = <1, 1, 1>\n[/OBJECT]\n\
            [OBJECT]\ntype = torus\nmajor = 1\nminor = 0.3\n[/OBJECT]\n[/CSG]\n\
            [CSG]\nop = difference\nrotate = <17, 29, 41>\n\
            [OBJECT]\ntype = cube\n[/OBJECT]\n\
            [OBJECT]\ntype = cube\nscale = <0.55, 2, 2>\ntranslate = <0.45, 0, 0>\n[/OBJECT]\n\
            [OBJECT]\ntype = cylinder\nradius = 0.4\nscale = <1, 3, 1>\n[/OBJECT]\n[/CSG]\n\
            [CSG]\nop = union\nrotate = <-20, 50, 10>\ntranslate = <3, -1.5, 0>\n\
            [OBJECT]\ntype = cube\nscale = 0.7\n[/OBJECT]\n\
            [OBJECT]\ntype = cone\nscale = 0.7\ntranslate = <0, 1.4, 0>\n[/OBJECT]\n\
            [OBJECT]\ntype = cylinder\nscale = 0.7\ntranslate = <1.4, 0, 0>\n[/OBJECT]\n[/CSG]\n";
    for offset in [DVec3::ZERO, DVec3::new(1e5, -2e5, 1e5)] {
        let (eye, at) = (DVec3::new(1.0, 2.0, 12.0) + offset, offset);
        let v = |p: DVec3| format!("<{}, {}, {}>", p.x, p.y, p.z);
        let moved = format!(
            "[CSG]\nop = union\ntranslate = {}\n{objects}[OBJECT]\ntype = sphere\nradius = 1e-3\ntranslate = <100, 0, 0>\n[/OBJECT]\n[/CSG]\n",
            v(offset)
        );
        let src = |shadow: f64| {
            format!(
                "[GLOBALS]\nwidth = 160\nheight = 120\nambient = 0.1\nshadow = {shadow}\n[/GLOBALS]\n\
                     [CAMERA]\neye = {}\nlook_at = {}\nfov = 45\n[/CAMERA]\n\
                     [LIGHT]\nposition = {}\n[/LIGHT]\n{moved}",
                v(eye),
                v(at),
                v(eye)
            )
        };
        let lit = render(&scene(&src(0.0)));
        let shadowed = render(&scene(&src(1.0)));
        let hit = lit.iter().filter(|c| c.max_element() > 0.0).count();
        assert!(hit > 2500, "only {hit} pixels show an object");
        let acne: Vec<usize> = (0..lit.len()).filter(|&i| lit[i] != shadowed[i]).collect();
        assert!(
            acne.is_empty(),
            "offset {offset:?}: {} acne pixels, first {:?}",
            acne.len(),
            &acne[..acne.len().min(5)]
        );
    }
}

/// The coincident-face rule seen in an image: a cube minus a cutter that shares its +x
/// face, turned arbitrarily, with the camera looking down the turned x axis. Every pixel
/// of the cut face shows the cutter's green; a sliver of the body's face would be red.
#[test]
fn coincident_difference_renders_without_speckles() {
    let rot = crate::transform::Transform::from_op(crate::transform::TransformOp::Rotate(
        DVec3::new(17.0, 29.0, 41.0),
    ));
    let eye = rot.to_world().transform_vector3(DVec3::new(10.0, 0.0, 0.0));
    let up = rot.to_world().transform_vector3(DVec3::Y);
    let s = scene(&format!(
        "[GLOBALS]\nwidth = 100\nheight = 100\nambient = 0.2\n[/GLOBALS]\n\
             [CAMERA]\neye = <{}, {}, {}>\nup = <{}, {}, {}>\nfov = 14\n[/CAMERA]\n\
             [LIGHT]\nposition = <{}, {}, {}>\n[/LIGHT]\n\
             [CSG]\nop = difference\nrotate = <17, 29, 41>\n\
             [OBJECT]\ntype = cube\ncolor1 = <1, 0, 0>\n[/OBJECT]\n\
             [OBJECT]\ntype = cube\nscale = <0.55, 2, 2>\ntranslate = <0.45, 0, 0>\ncolor1 = <0, 1, 0>\n[/OBJECT]\n\
             [/CSG]\n",
        eye.x, eye.y, eye.z, up.x, up.y, up.z, eye.x, eye.y, eye.z
    ));
    let img = render(&s);
    let mut green = 0;
    for (i, c) in img.iter().enumerate() {
        assert_eq!(c.x, 0.0, "pixel {i} shows the body's face: {c:?}");
        green += usize::from(c.y > 0.5);
    }
    // The cut face fills the middle of the view (|y|, |z| < 1 seen from 11 away).
    assert!(green > 3000, "{green}");
}

/// A checkered cube whose faces lie exactly on cell boundaries (x = ±1), turned so that
/// object-space coordinates are inexact: every pixel shows the cell its analytic hit
/// point lies in. Without snapping the face coordinate to ±1, `floor(0.999…)` would
/// flip about half the pixels of some faces to the other colour.
#[test]
fn checkered_cube_faces_have_no_speckle() {
    let s = scene(
        "[GLOBALS]\nwidth = 120\nheight = 120\nambient = 1\n[/GLOBALS]\n\
             [CAMERA]\neye = <4, 5, 12>\nfov = 30\n[/CAMERA]\n\
             [OBJECT]\ntype = cube\nscale = 2.5\nrotate = <10, 25, 0>\n\
             color1 = 1\ncolor2 = 0.25\n[/OBJECT]\n",
    );
    let img = render(&s);
    let obj = &s.objects[0];
    let mut checked = 0;
    for y in 0..120u32 {
        for x in 0..120u32 {
            let r = obj
                .transform
                .ray_to_object(&s.camera.ray(f64::from(x) + 0.5, f64::from(y) + 0.5));
            // The nearest face plane crossing inside its face, by brute force.
            let mut best: Option<(f64, DVec3)> = None;
            for axis in 0..3 {
                for side in [-1.0, 1.0] {
                    let t = (side - r.origin[axis]) / r.dir[axis];
                    let mut p = r.at(t);
                    p[axis] = side;
                    let on_face = (0..3).all(|i| i == axis || p[i].abs() <= 1.0);
                    if t > 0.0 && on_face && best.is_none_or(|(bt, _)| t < bt) {
                        best = Some((t, p));
                    }
                }
            }
            let got = img[(y * 120 + x) as usize].x;
            let Some((_, p)) = best else {
                assert_eq!(got, 0.0);
                continue;
            };
            // Skip pixels within 1e-6 of a cell edge inside the face (x = 0 lines).
            if (0..3).any(|i| p[i].abs() < 1e-6 || (p[i].abs() > 1.0 - 1e-6 && p[i].abs() < 1.0)) {
                continue;
            }
            let parity = (p.x.floor() + p.y.floor() + p.z.floor()) as i64 & 1;
            let expect = if parity == 0 { 1.0 } else { 0.25 };
            assert_eq!(got, expect, "pixel ({x}, {y}) at {p:?}");
            checked += 1;
        }
    }
    assert!(checked > 4000, "{checked}");
}

/// Mirrors see CSG: a mirror floor under a sphere whose lower part is cut away by a
/// green cube shows the green cut face, which the camera cannot see directly; and the
/// mirror rays' own shadows through the CSG are consistent (the reflected face is lit by
/// a light low enough to reach it).
#[test]
fn a_mirror_shows_the_cut_face_underneath() {
    let s = scene(
        "[GLOBALS]\nwidth = 120\nheight = 90\nambient = 0.2\n[/GLOBALS]\n\
             [CAMERA]\neye = <0, 3.5, 12>\nlook_at = <0, 1, 0>\nfov = 30\n[/CAMERA]\n\
             [LIGHT]\nposition = <0, 0.3, 8>\n[/LIGHT]\n\
             [OBJECT]\ntype = plane\nmirror = 1\n[/OBJECT]\n\
             [CSG]\nop = difference\ntranslate = <0, 2.5, 0>\n\
             [OBJECT]\ntype = sphere\ncolor1 = <0.9, 0.1, 0.1>\n[/OBJECT]\n\
             [OBJECT]\ntype = cube\nscale = 2\ntranslate = <0, -2.5, 0>\ncolor1 = <0.1, 0.9, 0.1>\n[/OBJECT]\n\
             [/CSG]\n",
    );
    let img = render(&s);
    // The horizon (the floor's far edge) is where camera rays turn level.
    let mut green_rows = Vec::new();
    for y in 0..90u32 {
        for x in 0..120u32 {
            let c = img[(y * 120 + x) as usize];
            if c.y > 2.0 * c.x && c.y > 0.05 {
                green_rows.push(y);
                let r = s.camera.ray(f64::from(x) + 0.5, f64::from(y) + 0.5);
                assert!(r.dir.y < 0.0, "green seen directly at ({x}, {y})");
            }
        }
    }
    assert!(green_rows.len() > 50, "{}", green_rows.len());
}

/// The example scenes build, with their textures, and show objects mid-image.
#[test]
fn examples_build_and_render() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
    for name in ["shapes.ray", "csg.ray"] {
        let src = std::fs::read_to_string(dir.join(name))
            .unwrap_or_else(|e| panic!("examples/{name}: {e}"));
        let s = Scene::from_source(
            &src,
            &Limits::default(),
            &crate::DirAssets::new(&dir),
            &TextureLimits::default(),
        )
        .unwrap_or_else(|e| panic!("examples/{name}: {e}"));
        let rect = Rect::new(s.width / 2 - 20, s.height / 2 - 20, 40, 40);
        let (px, _) = s.render_rect_linear(rect);
        assert!(px.iter().any(|c| *c != s.background), "examples/{name}");
    }
}

/// A plain white Lambertian object: the shape and placement are what a test varies.
fn white(shape: Shape, t: Transform) -> Object {
    Object::new(
        shape,
        t,
        DVec3::ONE,
        Material {
            color1: Color::ONE,
            color2: None,
            texture: None,
            mirror: 0.0,
            diffuse: 1.0,
        },
        false,
    )
}

/// Whether `obj`'s world-space pre-test rejects `ray`, asserting that the exact test in the
/// object's space finds no hit on a ray it rejects.
fn rejects_only_misses(obj: &Object, ray: &Ray) -> bool {
    let rejected = obj.certainly_missed_by(ray);
    if rejected {
        let exact = obj
            .shape
            .intersect(&obj.transform.ray_to_object(ray), f64::INFINITY);
        assert!(
            exact.is_none(),
            "rejected a hit: {ray:?} on {:?} placed by {:?}",
            obj.shape,
            obj.transform
        );
    }
    rejected
}

/// The sphere pre-test never rejects a ray the exact test hits: rays grazing the
/// silhouette within 1e-9 of the radius (either side), from near and from 1e6 radii away,
/// on spheres large and small, near the origin and far from it.
#[test]
fn sphere_pre_test_rejects_only_misses() {
    let mut rng = Rng::new(99);
    let mut rejected = 0;
    for _ in 0..20000 {
        let r = 10f64.powf(rng.range(-3.0, 3.0));
        let c = rng.in_ball(1.0) * 10f64.powf(rng.range(0.0, 5.0));
        let t = Transform::from_op(crate::transform::TransformOp::Scale(DVec3::splat(r))).then(
            &Transform::from_op(crate::transform::TransformOp::Translate(c)),
        );
        let obj = white(Shape::Sphere, t);
        let dist = r * 10f64.powf(rng.range(0.0, 6.0));
        let o = c + rng.direction() * dist;
        let to = c - o;
        let side = to.any_orthonormal_vector();
        // Aim within 1e-9 (relative) of the silhouette, or anywhere near it.
        let offset = if rng.range(0.0, 1.0) < 0.5 {
            r * (1.0 + rng.range(-1e-9, 1e-9))
        } else {
            r * rng.range(0.0, 3.0)
        };
        let ray = Ray::new(o, (c + side * offset - o) * rng.range(0.1, 10.0));
        if rejects_only_misses(&obj, &ray) {
            rejected += 1;
        }
    }
    assert!(rejected > 2000, "{rejected}");
}

/// The cylinder's and cone's pre-test (the tube around the axis) never rejects a ray the
/// exact test hits: lines tangent to the side, 1e-17 to 1e-9 of its size away on either
/// side (the failure case of a margin too thin), on rods from a thousandth to a hundred units thick,
/// sheared, turned and placed up to 1e5 away, seen from near and from 1e6 sizes away.
#[test]
fn rod_pre_test_rejects_only_misses() {
    use crate::transform::TransformOp::{Rotate, Scale, Translate};
    let mut rng = Rng::new(7);
    let (mut rejected, mut tried) = (0, 0);
    let scale = |rng: &mut Rng, lo: f64, hi: f64| {
        DVec3::new(
            10f64.powf(rng.range(lo, hi)),
            10f64.powf(rng.range(lo, hi)),
            10f64.powf(rng.range(lo, hi)),
        )
    };
    for k in 0..20000 {
        let shape = if k % 2 == 0 {
            Shape::Cylinder
        } else {
            Shape::Cone
        };
        // Half of them round in section and not sheared, where the tube fits the side
        // exactly: a tangent line is then as far from the axis as the tube's radius.
        let (mut a, mut b) = (scale(&mut rng, -3.0, 2.0), scale(&mut rng, -0.5, 0.5));
        if k % 4 < 2 {
            (a.z, b) = (a.x, DVec3::splat(b.x));
        }
        let angles = rng.in_ball(180.0);
        let t = Transform::from_op(Scale(a))
            .then(&Transform::from_op(Rotate(angles)))
            .then(&Transform::from_op(Scale(b)))
            .then(&Transform::from_op(Translate(
                rng.in_ball(1.0) * 10f64.powf(rng.range(0.0, 5.0)),
            )));
        if !t.is_valid() {
            continue;
        }
        tried += 1;
        let obj = white(shape, t);
        // A point on the side, its outward normal, and a tangent there, in world space.
        let (y, phi) = (rng.range(-1.0, 1.0), rng.range(0.0, std::f64::consts::TAU));
        let rho = if shape == Shape::Cone {
            (1.0 - y) / 2.0
        } else {
            1.0
        };
        let (c, s) = (phi.cos(), phi.sin());
        let local = DVec3::new(rho * c, y, rho * s);
        let local_n = if shape == Shape::Cone {
            DVec3::new(c, 0.5, s)
        } else {
            DVec3::new(c, 0.0, s)
        };
        let m = t.to_world().matrix3;
        let p = t.to_world().transform_point3(local);
        let n = t.normal_to_world(local_n).normalize();
        let along = if shape == Shape::Cone {
            DVec3::new(-c, 2.0, -s)
        } else {
            DVec3::Y
        };
        let tangent = (m
            * (DVec3::new(-s, 0.0, c) * rng.range(-1.0, 1.0) + along * rng.range(-1.0, 1.0)))
        .normalize();
        let size = (m * DVec3::new(1.0, 1.0, 1.0)).length();
        let offset = if rng.range(0.0, 1.0) < 0.5 {
            let sign = if rng.range(0.0, 1.0) < 0.5 { -1.0 } else { 1.0 };
            sign * size * 10f64.powf(rng.range(-17.0, -9.0))
        } else {
            size * rng.range(0.0, 3.0)
        };
        let dist = size * 10f64.powf(rng.range(0.0, 6.0));
        let ray = Ray::new(
            p + n * offset - tangent * dist,
            tangent * rng.range(0.1, 10.0),
        );
        if !ray.dir.is_finite() || !ray.origin.is_finite() {
            continue;
        }
        if rejects_only_misses(&obj, &ray) {
            rejected += 1;
        }
    }
    assert!(tried > 15000, "{tried}");
    assert!(rejected > 2000, "{rejected}");
}

#[test]
fn random_csg_rays_are_finite_and_within_t_max() {
    let s = scene(
        "[CSG]\nop = intersection\n\
             [CSG]\nop = difference\n[OBJECT]\ntype = torus\nmajor = 1\nminor = 0.5\n[/OBJECT]\n\
             [OBJECT]\ntype = cone\n[/OBJECT]\n[/CSG]\n\
             [OBJECT]\ntype = cylinder\nradius = 1.4\nscale = <1, 0.3, 1>\n[/OBJECT]\n[/CSG]\n",
    );
    let mut rng = Rng::new(41);
    for _ in 0..3000 {
        let o = rng.in_ball(3.0);
        let r = Ray::new(o, rng.in_ball(2.0) - o);
        let t_max = rng.range(0.0, 3.0);
        if let Some(h) = s.intersect(&r, t_max, None) {
            assert!(h.local.t > 0.0 && h.local.t < t_max);
            assert!(h.local.p.is_finite() && h.local.n.is_finite());
            assert!(s.occluded(&r, t_max, None));
        } else {
            assert!(!s.occluded(&r, t_max, None));
        }
    }
}
/// The slices of a cylinder or cone hold every hit on it, under transforms that turn,
/// stretch and shear it (a CSG-free composition of scales and rotations), with rays
/// aimed at the surface, at the rim and along the axis; and a long rod laid diagonally
/// is cut into several slices whose boxes are far smaller in total than its own box.
#[test]
fn pieces_hold_every_hit() {
    use crate::transform::TransformOp;
    let mut rng = Rng::new(5);
    let mut hits = 0;
    for k in 0..400 {
        let shape = if k % 2 == 0 {
            Shape::Cylinder
        } else {
            Shape::Cone
        };
        let op = |o| Transform::from_op(o);
        let len = 10f64.powf(rng.range(-1.0, 2.0));
        let t = op(TransformOp::Scale(DVec3::new(
            rng.range(0.01, 1.0),
            len,
            rng.range(0.01, 1.0),
        )))
        .then(&op(TransformOp::Rotate(rng.in_ball(180.0))))
        .then(&op(TransformOp::Scale(DVec3::new(
            rng.range(0.5, 2.0),
            rng.range(0.5, 2.0),
            rng.range(0.5, 2.0),
        ))))
        .then(&op(TransformOp::Rotate(rng.in_ball(180.0))))
        .then(&op(TransformOp::Translate(rng.in_ball(1e3))));
        let obj = white(shape, t);
        let pieces: Vec<Aabb> = obj
            .pieces()
            .iter()
            .map(|b| crate::bvh::padded(b).expect("a finite transform gives finite slices"))
            .collect();
        assert!(!pieces.is_empty() && pieces.len() <= MAX_PIECES);
        let whole = obj.bounds.expect("bounded shape");
        for _ in 0..100 {
            // A target on the solid: its surface, rim or axis, in object space.
            let y = [-1.0, 1.0, rng.range(-1.0, 1.0)][rng.range(0.0, 3.0) as usize];
            let rho = if shape == Shape::Cone {
                (1.0 - y) / 2.0
            } else {
                1.0
            };
            let phi = rng.range(0.0, std::f64::consts::TAU);
            let r = rho * [1.0, rng.range(0.0, 1.0), 0.0][rng.range(0.0, 3.0) as usize];
            let target = t
                .to_world()
                .transform_point3(DVec3::new(r * phi.cos(), y, r * phi.sin()));
            let o = target + rng.direction() * rng.range(0.1, 1e4);
            let ray = Ray::new(o, (target - o) * rng.range(0.1, 10.0));
            let Some(h) = obj.shape.intersect(&t.ray_to_object(&ray), f64::INFINITY) else {
                continue;
            };
            hits += 1;
            let inv = ray.inv_dir();
            assert!(
                pieces.iter().any(|b| {
                    b.hit_interval(o, inv, h.t + h.t * crate::bvh::SLACK)
                        .is_some()
                }),
                "{shape:?} {k}: hit at t = {} in no slice",
                h.t
            );
        }
        // Never looser than the box of the transformed unit cube (up to the padding).
        let (lo, hi) = pieces
            .iter()
            .fold((DVec3::INFINITY, DVec3::NEG_INFINITY), |(a, b), p| {
                (a.min(p.min), b.max(p.max))
            });
        let pad =
            (whole.max - whole.min).max_element() * 1e-6 + whole.max.abs().max_element() * 1e-6;
        assert!(lo.cmpge(whole.min - pad).all() && hi.cmple(whole.max + pad).all());
    }
    assert!(hits > 20000, "{hits}");
    // A rod of radius 0.1 and length 14 at 35° in the xy plane: cut, and much tighter.
    let rod = scene(
        "[OBJECT]\ntype = cylinder\nradius = 0.1\nscale = <1, 7, 1>\nrotate = <0, 0, 35>\n[/OBJECT]\n",
    );
    let obj = &rod.objects[0];
    let pieces = obj.pieces();
    let area: f64 = pieces.iter().map(Aabb::surface_area).sum();
    let whole = obj.bounds.expect("bounded").surface_area();
    assert!(pieces.len() >= 8, "{}", pieces.len());
    assert!(area < 0.2 * whole, "{area} vs {whole}");
    // Shapes that are not cut.
    for shape in ["sphere", "cube", "torus\nmajor = 1\nminor = 0.2"] {
        let s = scene(&format!(
            "[OBJECT]\ntype = {shape}\nscale = <1, 9, 1>\n[/OBJECT]\n"
        ));
        assert!(s.objects[0].pieces().is_empty(), "{shape}");
    }
}

/// A rectangle rendered to bytes a band of rows at a time gives the bytes of its pixels
/// rendered whole, with the same rays, for every sampler (the adaptive one is not banded);
/// and a render told to stop gives nothing.
#[test]
fn a_rectangle_rendered_in_bands_is_the_rectangle_rendered_whole() {
    use std::sync::atomic::AtomicBool;
    // 300 pixels wide: bands of 13 rows, the last one short.
    let s = scene(
        "[GLOBALS]\nwidth = 300\nheight = 40\nlight = <5, 10, 10>\n[/GLOBALS]\n\
         [CAMERA]\neye = <0, 2, 8>\nlook_at = <0, 0.5, 0>\n[/CAMERA]\n\
         [OBJECT]\ntype = plane\ncolor1 = 0.9\ncolor2 = 0.1\n[/OBJECT]\n\
         [OBJECT]\ntype = sphere\ntranslate = <0, 1, 0>\nmirror = 0.5\n[/OBJECT]\n",
    );
    let rect = Rect::new(3, 2, 297, 38);
    for sampler in [
        crate::Sampler::Center,
        crate::Sampler::Thesis,
        crate::Sampler::Jitter { n: 2 },
        crate::Sampler::Adaptive {
            max: 4,
            threshold: 0.05,
        },
    ] {
        let (linear, whole) = s.render_rect_linear_with(rect, &sampler);
        let expected: Vec<u8> = linear
            .iter()
            .flat_map(|&c| crate::srgb::encode_rgb8(c))
            .collect();
        let (bytes, banded) = s.render_rect_stats_with(rect, &sampler);
        assert!(bytes == expected, "{sampler:?}: the bands' bytes differ");
        assert_eq!(banded.total(), whole.total(), "{sampler:?}");
    }
    let stop = AtomicBool::new(true);
    assert!(
        s.render_rect_stats_until(rect, &crate::Sampler::Center, &stop)
            .is_none()
    );
}

/// The shadow pre-test of a scene searched solid by solid (`Scene::shadow_certainly_clear`)
/// never clears a shadow ray that the full search finds blocked. The failure case is a ray
/// grazing a solid's limb: here rays from a floor to a light pass a sphere's centre, or the
/// centre of a difference whose body is a sphere, at `r·(1 + ε)` for `|ε|` from 1e-12 to
/// 0.1 on either side, with the scene at the origin and 1e5 away. The test is not vacuous:
/// it clears most of the rays that pass a sphere placed by a similarity beyond 1e-3 of its
/// radius, and the rays that pass inside are blocked.
#[test]
fn shadow_pre_test_clears_only_unblocked_rays() {
    use crate::render::{SHADOW_END_REL, SurfacePoint};
    let mut rng = Rng::new(7);
    let (mut cleared, mut blocked, mut wide, mut wide_cleared) = (0, 0, 0, 0);
    for case in 0..200 {
        let far = if case % 2 == 0 {
            DVec3::ZERO
        } else {
            DVec3::new(1e5, -3e4, 7e4) * rng.range(0.5, 1.0)
        };
        let r = 10f64.powf(rng.range(-2.0, 1.0));
        let c = far
            + DVec3::new(
                rng.range(-3.0, 3.0),
                r * rng.range(1.2, 3.0),
                rng.range(-3.0, 3.0),
            );
        let lift = DVec3::new(
            rng.range(-5.0, 5.0),
            rng.range(3.0, 20.0),
            rng.range(-5.0, 5.0),
        );
        let light = c + lift * (1.0 + r);
        let at = |p: DVec3| format!("<{:e}, {:e}, {:e}>", p.x, p.y, p.z);
        // A sphere placed by a similarity, a turned one, and two trees.
        let turn = at(rng.in_ball(90.0) * f64::from(case % 4));
        let solid = if case % 4 < 2 {
            format!(
                "[OBJECT]\ntype = sphere\nradius = {r:e}\nrotate = {turn}\ntranslate = {}\n[/OBJECT]\n",
                at(c)
            )
        } else {
            format!(
                "[CSG]\nop = difference\nrotate = {turn}\ntranslate = {}\n\
                 [OBJECT]\ntype = sphere\nradius = {r:e}\n[/OBJECT]\n\
                 [OBJECT]\ntype = cube\nscale = {:e}\ntranslate = <{:e}, 0, 0>\n[/OBJECT]\n[/CSG]\n",
                at(c),
                0.3 * r,
                r
            )
        };
        let s = scene(&format!(
            "[GLOBALS]\nshadow = 1\n[/GLOBALS]\n[LIGHT]\nposition = {}\n[/LIGHT]\n\
             [OBJECT]\ntype = plane\nscale = 3\ntranslate = {}\n[/OBJECT]\n{solid}",
            at(light),
            at(far)
        ));
        assert!(matches!(s.accel, Accel::Linear(_)));
        for _ in 0..50 {
            // The line from the light passing the centre at distance `r·(1 + ε)`...
            let eps = 10f64.powf(rng.range(-12.0, -1.0))
                * if rng.range(0.0, 1.0) < 0.5 { -1.0 } else { 1.0 };
            let (axis, l) = ((c - light).normalize(), (c - light).length());
            let side = rng.direction();
            let w = (side - axis * side.dot(axis)).normalize();
            // Through `c + w·t`, square to the axis: its distance from `c` is `t·l/√(l² + t²)`.
            let d = r * (1.0 + eps);
            let dir = c + w * (d * l / (l * l - d * d).sqrt()) - light;
            // ... meets the floor here, where a ray from above finds its hit.
            let target = light + dir * ((far.y - light.y) / dir.y);
            let from = target + DVec3::new(0.3, 5.0, 0.2);
            let ray = Ray::new(from, target - from);
            let Some(hit) = s.intersect(&ray, f64::INFINITY, None) else {
                continue;
            };
            if hit.object != 0 {
                continue;
            }
            let sp = SurfacePoint::new(&s.objects[0], &hit.local, ray.dir);
            let skip = s.self_skip(&hit, sp.outside);
            let clear = s.shadow_certainly_clear(sp.p, || sp.reach(), light, skip);
            let origin = sp.origin_ahead();
            let shadow = Ray::new(origin, light - origin);
            let end = 1.0 - SHADOW_END_REL * (origin.length() / shadow.dir.length() + 1.0);
            let is_blocked = s.occluded(&shadow, end, skip);
            assert!(
                !(clear && is_blocked),
                "cleared a blocked shadow ray: eps {eps:e}, r {r:e}, far {far:?}, {solid}"
            );
            cleared += usize::from(clear);
            blocked += usize::from(is_blocked);
            if eps > 1e-3 && case % 4 == 0 {
                wide += 1;
                wide_cleared += usize::from(clear);
            }
        }
    }
    assert!(
        cleared > 400 && blocked > 2000,
        "{cleared} cleared, {blocked} blocked"
    );
    assert!(
        wide_cleared * 10 > wide * 9,
        "{wide_cleared} of {wide} wide misses cleared"
    );
}
