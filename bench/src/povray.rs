//! Side by side with POV-Ray 3.7: the same scene, resolution, samples (one ray per pixel) and
//! threads (one), POV-Ray's own reported trace time against ours, and the two images'
//! difference, so the comparison is known to be about the same picture.
//!
//! The translation (`to_pov`) maps the `.ray` model onto POV-Ray's:
//! - coordinates: POV-Ray is left-handed, so z is negated everywhere; every matrix becomes
//!   `F·M·F` with `F = diag(1, 1, −1)`, and pattern space gets the same flip so a checker's
//!   cells keep their parity;
//! - camera: POV-Ray's `angle` is the horizontal field of view, derived from ours (vertical);
//! - lights: POV-Ray's shadows are all-or-nothing, so a light with `shadow = s` becomes a
//!   shadowless light of `(1 − s)·colour` plus a shadowed one of `s·colour`, which sums to
//!   exactly our `V = 1 − s` where blocked;
//! - finishes: `L = (1 − m)·local + m·reflected` becomes `ambient (1 − m)`, `diffuse k(1 − m)`,
//!   `reflection m` with the scene's ambient as POV-Ray's `ambient_light`; `max_depth` bounces
//!   are `max_trace_level = max_depth + 1`, and `adc_bailout 0` so POV-Ray stops no ray early;
//! - the plane's checker is offset half a cell in y so POV-Ray's solid checker never evaluates
//!   at y = 0 exactly (its `floor(±0)` would be noise, the failure our own plane avoids).
//!
//! Shapes and CSG map one to one (POV-Ray's `difference` is also the first child minus the
//! rest). Textures are not translated (their u,v conventions differ); scenes using them are
//! skipped.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use glam::{DAffine3, DVec3};
use tessera_tracer::{
    CsgOp, Light, MaterialDesc, MemoryAssets, Node, ObjectDesc, Rect, Sampler, Scene, SceneDesc,
    Shape, TextureLimits, Transform,
};

use crate::stats::{Spread, median};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Scenes to compare (`.ray` files or directories of them); by default the chart's
    /// scenes and `bench/scenes-perf` (CSG), which only the speed comparisons use.
    #[arg(long, default_values = ["bench/scenes", "bench/scenes-perf"])]
    scenes: Vec<PathBuf>,
    /// Smaller images (for CI).
    #[arg(long)]
    quick: bool,
    /// The POV-Ray executable.
    #[arg(long, default_value = "povray")]
    povray: String,
    /// Timed runs of each renderer; the median is reported.
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// Multiply each scene's width and height by this, 1 to 16 (default 8, or 1 with
    /// `--quick`). At the scenes' own 160×120 POV-Ray's trace time (10–30 ms, reported in
    /// whole milliseconds) is coarse and includes several milliseconds of fixed cost, which
    /// flatters the ratio; at 1280×960 it is a few percent.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=16))]
    scale: Option<u32>,
}

fn flip(v: DVec3) -> DVec3 {
    DVec3::new(v.x, v.y, -v.z)
}

fn vec(v: DVec3) -> String {
    format!("<{:.17e}, {:.17e}, {:.17e}>", v.x, v.y, v.z)
}

/// `F·M·F` as POV-Ray's `matrix` (row-vector convention: `p' = p·A + t`).
fn matrix(t: &Transform) -> String {
    let m: &DAffine3 = t.to_world();
    let f = |v: DVec3| flip(v);
    // Columns of F·L·F are F·(L·(F·e_i)): the images of the flipped basis, flipped back.
    let cx = f(m.matrix3 * f(DVec3::X));
    let cy = f(m.matrix3 * f(DVec3::Y));
    let cz = f(m.matrix3 * f(DVec3::Z));
    let tr = f(m.translation);
    // POV-Ray's rows are the images of the basis vectors: our columns.
    format!(
        "matrix <{:.17e}, {:.17e}, {:.17e}, {:.17e}, {:.17e}, {:.17e}, {:.17e}, {:.17e}, {:.17e}, {:.17e}, {:.17e}, {:.17e}>",
        cx.x, cx.y, cx.z, cy.x, cy.y, cy.z, cz.x, cz.y, cz.z, tr.x, tr.y, tr.z
    )
}

fn finish(m: &MaterialDesc) -> String {
    let keep = 1.0 - m.mirror;
    let mut s = format!(
        "finish {{ ambient {keep:.17e} diffuse {:.17e}",
        m.diffuse * keep
    );
    if m.mirror > 0.0 {
        let _ = write!(s, " reflection {{ {:.17e} }}", m.mirror);
    }
    s.push_str(" }");
    s
}

fn pigment(o: &ObjectDesc) -> Result<String> {
    let m = &o.material;
    if m.texture.is_some() {
        bail!("textures are not translated to POV-Ray");
    }
    let c1 = m.color1;
    let Some(c2) = m.color2 else {
        return Ok(format!("pigment {{ rgb {} }}", vec(c1)));
    };
    // Cells are unit cubes of the own space: in the unit shape's space they are 1/own_scale;
    // z flipped so POV-Ray's object space (z-negated) sees our parity.
    let s = o.own_scale;
    let mut p = format!(
        "pigment {{ checker rgb {}, rgb {} scale <{:.17e}, {:.17e}, {:.17e}>",
        vec(c1),
        vec(c2),
        1.0 / s.x,
        1.0 / s.y,
        -1.0 / s.z
    );
    if o.shape == Shape::Plane {
        p.push_str(" translate <0, -0.5, 0>");
    }
    p.push_str(" }");
    Ok(p)
}

fn object(o: &ObjectDesc) -> Result<String> {
    // The unit shapes are the same in both languages; the radius is in the matrix.
    let body = match o.shape {
        Shape::Sphere => "sphere { 0, 1".to_string(),
        Shape::Plane => "plane { y, 0".to_string(),
        Shape::Cube => "box { -1, 1".to_string(),
        Shape::Cylinder => "cylinder { <0, -1, 0>, <0, 1, 0>, 1".to_string(),
        Shape::Cone => "cone { <0, -1, 0>, 1, <0, 1, 0>, 0".to_string(),
        Shape::Torus { major, minor } => format!("torus {{ {major:.17e}, {minor:.17e}"),
    };
    Ok(format!(
        "{body} {} {} {} }}\n",
        pigment(o)?,
        finish(&o.material),
        matrix(&o.transform)
    ))
}

fn node(n: &Node) -> Result<String> {
    match n {
        Node::Object(o) => object(o),
        Node::Csg(c) => {
            let op = match c.op {
                CsgOp::Union => "union",
                CsgOp::Intersection => "intersection",
                CsgOp::Difference => "difference",
            };
            let mut s = format!("{op} {{\n");
            for child in &c.children {
                s.push_str(&node(child)?);
            }
            let _ = writeln!(s, "{} }}", matrix(&c.transform));
            Ok(s)
        }
    }
}

fn light(l: &Light, shadow: f64) -> String {
    let p = vec(flip(l.position));
    let c = l.color;
    match shadow {
        s if s >= 1.0 => format!("light_source {{ {p} rgb {} }}\n", vec(c)),
        s if s <= 0.0 => format!("light_source {{ {p} rgb {} shadowless }}\n", vec(c)),
        s => format!(
            "light_source {{ {p} rgb {} shadowless }}\nlight_source {{ {p} rgb {} }}\n",
            vec(c * (1.0 - s)),
            vec(c * s)
        ),
    }
}

/// The scene in POV-Ray 3.7's language.
pub fn to_pov(d: &SceneDesc) -> Result<String> {
    let aspect = f64::from(d.width) / f64::from(d.height);
    let h_fov = 2.0 * ((d.camera.fov_degrees.to_radians() / 2.0).tan() * aspect).atan();
    let mut s = String::from("#version 3.7;\n");
    let _ = writeln!(
        s,
        "global_settings {{ assumed_gamma 1.0 max_trace_level {} adc_bailout 0 ambient_light rgb {} }}",
        d.max_depth + 1,
        vec(d.ambient)
    );
    let _ = writeln!(
        s,
        "camera {{ perspective location {} look_at {} sky {} right x*{aspect:.17e} up y angle {:.17e} }}",
        vec(flip(d.camera.eye)),
        vec(flip(d.camera.look_at)),
        vec(flip(d.camera.up)),
        h_fov.to_degrees()
    );
    let _ = writeln!(s, "background {{ rgb {} }}", vec(d.background));
    for l in &d.lights {
        s.push_str(&light(l, d.shadow));
    }
    for n in &d.objects {
        s.push_str(&node(n)?);
    }
    Ok(s)
}

/// POV-Ray's reported trace time, in seconds, from its statistics output.
fn trace_seconds(output: &str) -> Option<f64> {
    let line = output
        .lines()
        .find(|l| l.trim_start().starts_with("Trace Time:"))?;
    let open = line.rfind('(')?;
    let secs = line[open + 1..].split_whitespace().next()?;
    secs.parse().ok()
}

/// Mean absolute difference (8-bit steps) and share of pixels differing by more than 2 steps.
pub(crate) fn image_difference(a: &[u8], b: &[u8]) -> (f64, f64) {
    let mut sum = 0u64;
    let mut off = 0usize;
    for (p, q) in a.chunks_exact(3).zip(b.chunks_exact(3)) {
        let d = p
            .iter()
            .zip(q)
            .map(|(x, y)| x.abs_diff(*y))
            .max()
            .unwrap_or(0);
        sum += u64::from(d);
        off += usize::from(d > 2);
    }
    let n = (a.len() / 3).max(1) as f64;
    (sum as f64 / n, off as f64 / n)
}

/// How many primary rays a pixel takes in one of the comparisons.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Rays {
    /// One ray through the pixel's centre, in both renderers.
    One,
    /// The thesis's five (Tessera's `sampler = thesis`: the centre and four points at ±1/4
    /// pixel) against POV-Ray's nearest: `+AM1 +A0.0 +R2 -J`, which takes every pixel's
    /// own ray and then a 2×2 grid in it, about five primary rays a pixel (its own count is
    /// printed beside the ratio).
    Five,
}

impl Rays {
    fn sampler(self) -> Sampler {
        match self {
            Rays::One => Sampler::Center,
            Rays::Five => Sampler::Thesis,
        }
    }

    fn povray_options(self) -> &'static [&'static str] {
        match self {
            Rays::One => &["-A", "+FN8", "File_Gamma=sRGB"],
            Rays::Five => &["+A0.0", "+AM1", "+R2", "-J", "+FN8", "File_Gamma=sRGB"],
        }
    }

    fn title(self) -> &'static str {
        match self {
            Rays::One => "one ray per pixel",
            Rays::Five => "the thesis's five rays per pixel (POV-Ray: +AM1 +A0.0 +R2 -J)",
        }
    }
}

pub fn run(args: &Args) -> Result<()> {
    let files = crate::scenes::scene_files(&args.scenes)?;
    if !available(&args.povray) {
        println!(
            "povray not found ({}): the comparison is skipped",
            args.povray
        );
        return Ok(());
    }
    let dir = std::env::temp_dir().join(format!("tessera-povray-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let result = [Rays::One, Rays::Five]
        .into_iter()
        .try_for_each(|rays| table(args, &files, &dir, rays));
    // The translated scenes and POV-Ray's images are of no use once compared.
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// One table: every scene at `rays` rays per pixel, Tessera against POV-Ray, then the
/// geometric mean of the ratios.
fn table(args: &Args, files: &[PathBuf], dir: &Path, rays: Rays) -> Result<()> {
    println!("\n{}", rays.title());
    println!(
        "{:<22} {:>9} {:>12} {:>12} {:>8} {:>15} {:>11} {:>10} {:>9}",
        "scene",
        "size",
        "tessera ms",
        "povray ms",
        "ratio",
        "ratio range",
        "pov ray/px",
        "mean |Δ|",
        "Δ>2 px"
    );
    let mut log_sum = 0.0;
    let mut count = 0usize;
    for path in files {
        let name = crate::scenes::scene_name(path);
        let mut desc = crate::scenes::read_desc(path)?;
        if args.quick {
            desc.width = (desc.width / 2).max(1);
            desc.height = (desc.height / 2).max(1);
        }
        let scale = args.scale.unwrap_or(if args.quick { 1 } else { 8 });
        desc.width = desc.width.saturating_mul(scale);
        desc.height = desc.height.saturating_mul(scale);
        desc.sampler = rays.sampler();
        let pov = match to_pov(&desc) {
            Ok(p) => p,
            Err(e) => {
                println!("{name:<22} skipped: {e}");
                continue;
            }
        };
        let scene = Scene::build(&desc, &MemoryAssets::new(), &TextureLimits::default())
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        // Pairs, back to back: on a machine whose speed drifts from second to second, a
        // Tessera run and the POV-Ray run right after it see the same machine, and the
        // median of the pairs' ratios moves less than the ratio of two separate medians.
        let input = dir.join(format!("{name}.pov"));
        let output = dir.join(format!("{name}.png"));
        std::fs::write(&input, &pov)?;
        let (mut ours_ms, mut pov_ms, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
        let mut ours = Vec::new();
        let mut pov_rays = 0.0;
        for _ in 0..args.repeats.max(1) {
            let (o_ms, o) = time_tessera(&scene);
            let p = time_povray(&args.povray, &input, &output, &desc, rays)
                .with_context(|| format!("POV-Ray on {name}"))?;
            ratios.push(p.ms / o_ms);
            ours_ms.push(o_ms);
            pov_ms.push(p.ms);
            pov_rays = p.primary_per_px;
            ours = o;
        }
        let theirs = image::open(&output)
            .with_context(|| format!("cannot read {}", output.display()))?
            .into_rgb8()
            .into_raw();
        let ratio = Spread::of(ratios);
        log_sum += ratio.median.ln();
        count += 1;
        let (mean, off) = image_difference(&ours, &theirs);
        println!(
            "{name:<22} {:>9} {:>12.1} {:>12.1} {:>7.2}× {:>15} {pov_rays:>11.2} {mean:>10.2} {:>8.2}%",
            format!("{}×{}", desc.width, desc.height),
            median(ours_ms),
            median(pov_ms),
            ratio.median,
            format!("{:.2}–{:.2}×", ratio.lo, ratio.hi),
            off * 100.0
        );
    }
    if count > 0 {
        println!(
            "geometric mean of the {count} ratios: {:.2}",
            (log_sum / count as f64).exp()
        );
    }
    println!(
        "(one thread; ratio = POV-Ray trace time / Tessera trace time, the median of {} \
         back-to-back pairs; pov ray/px = POV-Ray's primary rays per pixel, its own count)",
        args.repeats.max(1)
    );
    Ok(())
}

/// One render of the whole scene on this thread: milliseconds and the sRGB bytes.
fn time_tessera(scene: &Scene) -> (f64, Vec<u8>) {
    let start = Instant::now();
    let rgb = scene.render_rect(Rect::full(scene.width, scene.height));
    (start.elapsed().as_secs_f64() * 1e3, rgb)
}

/// What one POV-Ray run reported: its trace time and its primary rays per pixel.
struct PovRun {
    ms: f64,
    primary_per_px: f64,
}

/// One POV-Ray run of `input` into `output` at `rays` rays per pixel: the trace time it
/// reports, and its primary rays per pixel (its `Pixels` and `Samples` counts: one ray per
/// pixel and the supersamples, over the image's pixels).
fn time_povray(
    povray: &str,
    input: &Path,
    output: &Path,
    desc: &SceneDesc,
    rays: Rays,
) -> Result<PovRun> {
    let text = run_povray(povray, input, output, desc, rays.povray_options())?;
    let secs = trace_seconds(&text).context("no \"Trace Time\" in POV-Ray's output")?;
    let traced = statistic(&text, "Pixels:").context("no pixel count in POV-Ray's output")?
        + statistic(&text, "Samples:").unwrap_or(0.0);
    let pixels = f64::from(desc.width) * f64::from(desc.height);
    Ok(PovRun {
        ms: secs * 1e3,
        primary_per_px: traced / pixels.max(1.0),
    })
}

/// Runs POV-Ray on `input` at the scene's size, one thread, no display, with `options`;
/// returns its statistics output.
fn run_povray(
    povray: &str,
    input: &Path,
    output: &Path,
    desc: &SceneDesc,
    options: &[&str],
) -> Result<String> {
    let out = Command::new(povray)
        .arg(format!("+I{}", input.display()))
        .arg(format!("+O{}", output.display()))
        .arg(format!("+W{}", desc.width))
        .arg(format!("+H{}", desc.height))
        .args(["+WT1", "-D", "-P"])
        .args(options)
        .output()
        .context("cannot run povray")?;
    let text =
        String::from_utf8_lossy(&out.stderr).to_string() + &String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        bail!(
            "povray failed: {}",
            text.lines().rev().take(5).collect::<Vec<_>>().join(" | ")
        );
    }
    Ok(text)
}

/// Whether the program `exe` runs (asked for its version): the benchmarks that need an
/// outside program (POV-Ray, valgrind) skip that part, with a note, where it does not.
pub(crate) fn available(exe: &str) -> bool {
    Command::new(exe).arg("--version").output().is_ok()
}

/// One of POV-Ray's anti-aliasing settings: its method (`+AM1`, a fixed grid where a
/// pixel differs from its neighbours; `+AM2`, recursive subdivision of the pixel's
/// corners), its depth (`+R`) and its threshold (`+A`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Antialias {
    pub(crate) method: u8,
    pub(crate) depth: u32,
    pub(crate) threshold: f64,
}

impl Antialias {
    /// The settings the chart compares: each method over the depths it is used at, each
    /// at a loose, a middling and a strict threshold.
    pub(crate) fn all() -> Vec<Antialias> {
        let mut out = Vec::new();
        for (method, depths) in [(1u8, &[2u32, 3, 4, 5][..]), (2, &[2, 3, 4][..])] {
            for &depth in depths {
                for threshold in [0.3, 0.1, 0.03] {
                    out.push(Antialias {
                        method,
                        depth,
                        threshold,
                    });
                }
            }
        }
        out
    }

    pub(crate) fn family(&self) -> String {
        format!("POV-Ray AM{}", self.method)
    }

    pub(crate) fn label(&self) -> String {
        format!(
            "POV-Ray AM{} R{} A{}",
            self.method, self.depth, self.threshold
        )
    }
}

/// What one anti-aliased POV-Ray render gave: its trace time, samples and rays per pixel
/// (its own counts), and the image in linear RGB.
pub(crate) struct Antialiased {
    pub(crate) time_ms: f64,
    pub(crate) samples_per_px: f64,
    pub(crate) rays_per_px: f64,
    pub(crate) image: Vec<tessera_tracer::Color>,
}

/// Renders `desc` (translated by [`to_pov`]) with POV-Ray's anti-aliasing `aa`, one thread,
/// into a 16-bit PNG with no gamma (so the image is linear RGB, within 2⁻¹⁶), in `dir`.
pub(crate) fn render_antialiased(
    povray: &str,
    desc: &SceneDesc,
    aa: Antialias,
    dir: &Path,
) -> Result<Antialiased> {
    let input = dir.join("scene.pov");
    let output = dir.join("scene.png");
    std::fs::write(&input, to_pov(desc)?)?;
    let options = [
        format!("+A{}", aa.threshold),
        format!("+AM{}", aa.method),
        format!("+R{}", aa.depth),
        "+FN16".to_string(),
        "File_Gamma=1.0".to_string(),
    ];
    let options: Vec<&str> = options.iter().map(String::as_str).collect();
    let text = run_povray(povray, &input, &output, desc, &options)?;
    let secs = trace_seconds(&text).context("no \"Trace Time\" in POV-Ray's output")?;
    let pixels = f64::from(desc.width) * f64::from(desc.height);
    let samples = statistic(&text, "Samples:").context("no sample count in POV-Ray's output")?;
    let rays = statistic(&text, "Rays:").context("no ray count in POV-Ray's output")?;
    let image = image::open(&output)
        .with_context(|| format!("cannot read {}", output.display()))?
        .into_rgb16()
        .into_raw()
        .chunks_exact(3)
        .map(|c| DVec3::new(c[0].into(), c[1].into(), c[2].into()) / 65535.0)
        .collect();
    Ok(Antialiased {
        time_ms: secs * 1e3,
        samples_per_px: samples / pixels,
        rays_per_px: rays / pixels,
        image,
    })
}

/// The number after `name` in POV-Ray's statistics (`Samples:  73602`, `Rays:  226359`): a
/// name that starts its line, or follows other figures after a run of spaces, so that
/// `Rays:` is not read from `Reflected Rays:`.
fn statistic(output: &str, name: &str) -> Option<f64> {
    output.lines().find_map(|line| {
        let at = line.find(name)?;
        let before = &line[..at];
        if !(before.trim().is_empty() || before.ends_with("  ")) {
            return None;
        }
        line[at + name.len()..]
            .split_whitespace()
            .next()?
            .parse()
            .ok()
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use tessera_tracer::{Limits, parse};

    #[test]
    fn reads_povray_trace_time() {
        let text = "Render Time:\n  Photon Time:      No photons\n  Trace Time:       0 hours  0 minutes  1 seconds (1.234 seconds)\n";
        assert_eq!(trace_seconds(text), Some(1.234));
        assert_eq!(trace_seconds("nothing here"), None);
    }

    #[test]
    fn reads_povray_sample_and_ray_counts() {
        let text = "Pixels:            20440   Samples:           73602   Smpls/Pxl: 3.60\n\
                    Reflected Rays:              132317\n\
                    Rays:             226359   Saved:                 0   Max Level: 7/7\n";
        assert_eq!(statistic(text, "Samples:"), Some(73602.0));
        assert_eq!(statistic(text, "Rays:"), Some(226359.0));
        assert_eq!(statistic(text, "Photons:"), None);
    }

    #[test]
    fn partial_shadow_splits_a_light_in_two() {
        let l = Light {
            position: DVec3::new(1.0, 2.0, 3.0),
            color: DVec3::ONE,
        };
        let s = light(&l, 0.25);
        assert_eq!(s.matches("light_source").count(), 2);
        assert!(s.contains("shadowless"));
        assert!(
            light(&l, 1.0).matches("light_source").count() == 1
                && !light(&l, 1.0).contains("shadowless")
        );
        assert!(s.contains("-3.0"), "z is flipped: {s}");
    }

    #[test]
    fn matrix_flips_handedness_consistently() {
        // A rotation about y by 90° maps +z to +x in our right-handed world; in POV-Ray's
        // left-handed one, -z (our +z) must go to +x.
        let t = Transform::from_op(tessera_tracer::TransformOp::Rotate(DVec3::new(
            0.0, 90.0, 0.0,
        )));
        let m = matrix(&t);
        let nums: Vec<f64> = m
            .trim_start_matches("matrix <")
            .trim_end_matches('>')
            .split(',')
            .map(|x| x.trim().parse().expect("a number"))
            .collect();
        // POV row for the z basis vector is the image of +z (POV) = image of our -z = -x.
        assert_eq!(&nums[6..9], &[-1.0, 0.0, 0.0]);
    }

    #[test]
    fn translates_shapes_lights_and_finishes() {
        let src = "[GLOBALS]\nshadow = 0.5\nlight = <1, 2, 3>\n[/GLOBALS]\n[OBJECT]\ntype = sphere\nradius = 2\ncolor2 = 0.1\nmirror = 0.5\n[/OBJECT]\n[OBJECT]\ntype = plane\n[/OBJECT]\n\
                   [CSG]\nop = difference\n[OBJECT]\ntype = cube\n[/OBJECT]\n[OBJECT]\ntype = torus\n[/OBJECT]\n[/CSG]\n";
        let pov = to_pov(&parse(src, &Limits::default()).expect("valid")).expect("translatable");
        assert!(pov.contains("sphere { 0, 1") && pov.contains("plane { y, 0"));
        assert!(pov.contains("checker") && pov.contains("reflection"));
        assert!(pov.contains("max_trace_level 6"));
        assert!(
            pov.contains("difference {") && pov.contains("box { -1, 1") && pov.contains("torus {")
        );
    }
}
