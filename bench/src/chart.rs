//! Speed against accuracy: every sampler over a range of sample counts and thresholds, on
//! scenes that stress sampling, measured against a high-rate reference of the exact image.
//!
//! For each scene and configuration the chart records the median render time of repeated
//! single-threaded runs (the image rendered in the tiles the CLI takes on one thread; the repeats
//! interleaved across configurations), the primary and total rays per pixel, and the RMS
//! and worst-pixel error in linear RGB. The reference is `n × n` stratified samples per
//! pixel; it is also computed at `n/2`, and since its RMS error falls as `n^-3/2` (see
//! `tessera_tracer::exact`), the difference between the two, divided by `2^1.5 − 1`,
//! estimates the reference's own error, which is printed so that errors near it are read
//! with care.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use rayon::prelude::*;
use tessera_tracer::internals::exact::error;
use tessera_tracer::{
    Color, DirAssets, Rect, Sampler, Scene, SceneDesc, TextureLimits, local_tile, tiles,
};

use crate::scenes::{read_desc, scene_files, scene_name};
use crate::stats::median;
use crate::svg::{Panel, Series};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A short run (small images, fewer settings, one repeat): for CI, so the benchmark
    /// cannot rot.
    #[arg(long)]
    quick: bool,
    /// Where the CSV and SVG go.
    #[arg(long, default_value = "bench/results")]
    out: PathBuf,
    /// Scenes to measure (`.ray` files or directories of them).
    #[arg(long, default_value = "bench/scenes")]
    scenes: Vec<PathBuf>,
    /// Timed runs per configuration; the median is reported.
    #[arg(long)]
    repeats: Option<usize>,
    /// The POV-Ray executable whose anti-aliasing the full run compares (skipped, with a
    /// note, where it is missing).
    #[arg(long, default_value = "povray")]
    povray: String,
    /// Valgrind, whose callgrind counts the instructions of the renders the summary compares
    /// (skipped, with a note, where it is missing).
    #[arg(long, default_value = "valgrind")]
    valgrind: String,
}

/// How much smaller the quick run's images are, a side.
const QUICK_SHRINK: u32 = 4;

/// One sampler setting, and the family (line on the chart) it belongs to.
#[derive(Debug, Clone)]
struct Config {
    family: String,
    label: String,
    sampler: Sampler,
}

fn configs(quick: bool) -> Vec<Config> {
    let ns: &[u32] = if quick { &[2, 4] } else { &[2, 3, 4, 6, 8] };
    let thresholds: &[f64] = if quick {
        &[0.05]
    } else {
        &[0.3, 0.2, 0.1, 0.07, 0.05, 0.03, 0.01]
    };
    let mut out = vec![
        Config {
            family: "center".into(),
            label: "center".into(),
            sampler: Sampler::Center,
        },
        Config {
            family: "thesis".into(),
            label: "thesis".into(),
            sampler: Sampler::Thesis,
        },
    ];
    let adaptive = |n: u32, t: f64| Config {
        family: format!("adaptive t={t}"),
        label: format!("adaptive {n}x{n} t={t}"),
        sampler: Sampler::Adaptive {
            max: n,
            threshold: t,
        },
    };
    for &n in ns {
        out.push(Config {
            family: "grid".into(),
            label: format!("grid {n}x{n}"),
            sampler: Sampler::Grid { n },
        });
        out.push(Config {
            family: "jitter".into(),
            label: format!("jitter {n}x{n}"),
            sampler: Sampler::Jitter { n },
        });
        out.extend(thresholds.iter().map(|&t| adaptive(n, t)));
    }
    // More caps for adaptive alone. Jitter at 12 × 12 or 16 × 16 costs 144 or 256 rays in
    // every pixel, but adaptive spends them only where a pixel needs them, and these caps
    // reach errors below jitter 8 × 8's that cap 8 cannot. An odd cap has no stages: a pixel
    // that goes on takes all `n × n` rays, a count between the even caps' around it.
    let higher: &[u32] = if quick { &[] } else { &[5, 7, 9, 12, 16] };
    for &n in higher {
        out.extend(thresholds.iter().map(|&t| adaptive(n, t)));
    }
    out
}

/// One measured point.
#[derive(Debug, Clone)]
struct Point {
    scene: String,
    family: String,
    label: String,
    primary_per_px: f64,
    rays_per_px: f64,
    time_ms: f64,
    rmse: f64,
    worst: f64,
    pareto: bool,
}

/// Loads a scene, optionally at reduced resolution (the camera keeps its field of view).
pub fn load(path: &Path, shrink: u32) -> Result<Scene> {
    let mut desc = read_desc(path)?;
    desc.width = (desc.width / shrink).max(1);
    desc.height = (desc.height / shrink).max(1);
    let dir = path.parent().unwrap_or(Path::new("."));
    Scene::build(&desc, &DirAssets::new(dir), &TextureLimits::default())
        .map_err(|e| anyhow::anyhow!("{}", e.with_file(&path.display().to_string())))
}

/// Renders the whole image with `sampler` on this thread, tile by tile; returns the pixels,
/// the seconds taken, and the primary and total rays.
fn render_timed(scene: &Scene, sampler: &Sampler) -> (Vec<Color>, f64, u64, u64) {
    let (w, h) = (scene.width, scene.height);
    let mut image = vec![Color::ZERO; (w * h) as usize];
    let (mut primary, mut total) = (0, 0);
    let start = Instant::now();
    for r in tiles(w, h, local_tile(w, h, 1)) {
        let (px, stats) = scene.render_rect_linear_with(r, sampler);
        primary += stats.primary;
        total += stats.total();
        for row in 0..r.height {
            let dst = ((r.y + row) * w + r.x) as usize;
            let src = (row * r.width) as usize;
            image[dst..dst + r.width as usize].copy_from_slice(&px[src..src + r.width as usize]);
        }
    }
    (image, start.elapsed().as_secs_f64(), primary, total)
}

/// The instructions of one [`render_timed`] run, counted by callgrind: this program started
/// again under `valgrind` as `__count SCENE QUICK LABEL`, which loads the scene as the chart
/// does and renders it once with the setting named `label`, the count taken over
/// [`render_counted`] alone (not the start, the parse or the build). Instructions do not
/// vary from run to run as times do, so they check the timed speed-ups.
fn count_instructions(valgrind: &str, scene: &Path, quick: bool, label: &str) -> Result<u64> {
    let exe = std::env::current_exe().context("cannot find this program to run it again")?;
    let out = std::process::Command::new(valgrind)
        .args([
            "--tool=callgrind",
            "--callgrind-out-file=/dev/null",
            "--collect-atstart=no",
            "--toggle-collect=*render_counted*",
        ])
        .arg(exe)
        .arg("__count")
        .arg(scene)
        .arg(if quick { "quick" } else { "full" })
        .arg(label)
        .output()
        .with_context(|| format!("cannot run {valgrind}"))?;
    let text = String::from_utf8_lossy(&out.stderr);
    anyhow::ensure!(
        out.status.success(),
        "callgrind failed on {label}: {}",
        text.lines().rev().take(5).collect::<Vec<_>>().join(" | ")
    );
    text.lines()
        .find_map(|l| {
            l.split_once("Collected :")
                .map(|(_, n)| n.trim().parse().ok())
        })
        .flatten()
        .with_context(|| format!("no instruction count from callgrind on {label}"))
}

/// The child of [`count_instructions`]: `SCENE QUICK LABEL`.
pub fn count_child(args: &[std::ffi::OsString]) -> Result<()> {
    let [scene, quick, label] = args else {
        anyhow::bail!("usage: __count SCENE quick|full LABEL");
    };
    let quick = quick == "quick";
    let label = label.to_string_lossy();
    let config = configs(quick)
        .into_iter()
        .find(|c| c.label == label)
        .with_context(|| format!("no setting {label}"))?;
    let scene = load(Path::new(scene), if quick { QUICK_SHRINK } else { 1 })?;
    std::hint::black_box(render_counted(&scene, &config.sampler));
    Ok(())
}

/// One [`render_timed`] run, kept a function of its own so that callgrind can count it.
#[inline(never)]
fn render_counted(scene: &Scene, sampler: &Sampler) -> usize {
    render_timed(scene, sampler).0.len()
}

/// The reference image at `n × n` samples per pixel, on all cores.
fn reference(scene: &Scene, n: u32) -> Vec<Color> {
    (0..scene.height)
        .into_par_iter()
        .flat_map_iter(|y| scene.reference_rect(Rect::new(0, y, scene.width, 1), n).0)
        .collect()
}

/// Whether an error of `rmse` reaches `target`: at most it, to within a billionth of it.
/// An adaptive pixel that takes jitter's very rays sums them in another order, so the same
/// estimates differ from jitter's in their last bits, and an image made of them may come out
/// above jitter's error by a few ulps.
fn reaches(rmse: f64, target: f64) -> bool {
    rmse <= target * (1.0 + 1e-9)
}

/// Marks the points no other point beats in both time and error.
fn mark_pareto(points: &mut [Point]) {
    for i in 0..points.len() {
        let (t, e) = (points[i].time_ms, points[i].rmse);
        points[i].pareto = !points
            .iter()
            .any(|q| q.time_ms <= t && q.rmse <= e && (q.time_ms < t || q.rmse < e));
    }
}

pub fn run(args: &Args) -> Result<()> {
    let quick = args.quick;
    let (shrink, n_ref, repeats) = if quick {
        (QUICK_SHRINK, 16, 1)
    } else {
        (1, 48, 5)
    };
    let repeats = args.repeats.unwrap_or(repeats).max(1);
    let files = scene_files(&args.scenes)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;

    let mut all: Vec<Point> = Vec::new();
    let mut panels = Vec::new();
    let mut summary = String::new();
    // POV-Ray's anti-aliasing beside ours, in full runs only (its renders take minutes).
    let povray = if quick {
        None
    } else if crate::povray::available(&args.povray) {
        let dir = std::env::temp_dir().join(format!("tessera-chart-{}", std::process::id()));
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        Some((args.povray.as_str(), dir))
    } else {
        println!(
            "povray not found ({}): its anti-aliasing is not compared",
            args.povray
        );
        None
    };
    let valgrind = if crate::povray::available(&args.valgrind) {
        Some(args.valgrind.as_str())
    } else {
        println!(
            "valgrind not found ({}): the summary's instructions are not counted",
            args.valgrind
        );
        None
    };
    for path in &files {
        let name = scene_name(path);
        let scene = load(path, shrink)?;
        let started = Instant::now();
        let exact = reference(&scene, n_ref);
        let half = reference(&scene, n_ref / 2);
        let (diff, _) = error(&exact, &half);
        let ref_err = diff / (2f64.powf(1.5) - 1.0);
        println!(
            "{name}: {}×{}, reference {n_ref}×{n_ref} in {:.1} s, its RMS error ≈ {ref_err:.2e}",
            scene.width,
            scene.height,
            started.elapsed().as_secs_f64()
        );
        let pixels = f64::from(scene.width * scene.height);
        // Repeats go round the configurations rather than one configuration at a time, so
        // that a burst of load from elsewhere on a shared machine spreads over many
        // configurations' runs instead of landing on all of one configuration's.
        let configs = configs(quick);
        let mut times = vec![Vec::with_capacity(repeats); configs.len()];
        let mut results = vec![None; configs.len()];
        for _ in 0..repeats {
            for (i, c) in configs.iter().enumerate() {
                let (img, secs, primary, total) = render_timed(&scene, &c.sampler);
                times[i].push(secs * 1e3);
                results[i] = Some((img, primary, total));
            }
        }
        let mut points = Vec::new();
        for ((c, t), result) in configs.into_iter().zip(times).zip(results) {
            let Some((img, primary, total)) = result else {
                continue;
            };
            let (rmse, worst) = error(&img, &exact);
            points.push(Point {
                scene: name.clone(),
                family: c.family,
                label: c.label,
                primary_per_px: primary as f64 / pixels,
                rays_per_px: total as f64 / pixels,
                time_ms: median(t),
                rmse,
                worst,
                pareto: false,
            });
        }
        mark_pareto(&mut points);
        for versus in adaptive_vs_jitter(&points) {
            let instructions = match (&valgrind, versus.adaptive) {
                (Some(v), Some(a)) => Some((
                    count_instructions(v, path, quick, &versus.jitter.label)?,
                    count_instructions(v, path, quick, &a.label)?,
                )),
                _ => None,
            };
            let line = versus.line(instructions);
            println!("  {line}");
            let _ = writeln!(summary, "{name}: {line}");
        }
        let rays = ray_map(
            &scene,
            &points,
            quick,
            &args.out.join(format!("rays-{name}.png")),
        )?;
        println!("  {rays}");
        for p in &points {
            println!(
                "  {:<26} {:>7.2} spp {:>8.2} rays/px {:>9.2} ms  RMSE {:.2e}  worst {:.3}{}",
                p.label,
                p.primary_per_px,
                p.rays_per_px,
                p.time_ms,
                p.rmse,
                p.worst,
                if p.pareto { "  *" } else { "" }
            );
        }
        panels.push(panel(&name, &points, ref_err));
        if let Some((exe, dir)) = &povray {
            let desc = read_desc(path)?;
            match antialiased(exe, &desc, &exact, repeats, &name, dir)? {
                Some(pov) => {
                    for line in povray_vs_tessera(&points, &pov) {
                        println!("  {line}");
                        let _ = writeln!(summary, "{name}: {line}");
                    }
                    all.extend(points);
                    all.extend(pov);
                }
                None => all.extend(points),
            }
        } else {
            all.extend(points);
        }
    }

    let csv = args.out.join("chart.csv");
    std::fs::write(&csv, to_csv(&all))
        .with_context(|| format!("cannot write {}", csv.display()))?;
    let svg_path = args.out.join("chart.svg");
    std::fs::write(&svg_path, crate::svg::render(&panels))
        .with_context(|| format!("cannot write {}", svg_path.display()))?;
    println!(
        "\n{summary}wrote {} and {}",
        csv.display(),
        svg_path.display()
    );
    Ok(())
}

/// Draws where adaptive spends its rays on `scene`, for the cheapest adaptive setting that
/// reaches jitter 8×8's error (or the strictest setting of the highest cap, where none
/// does, or jitter 8×8 was not run): each pixel's count of primary rays, grey on a log
/// scale from black (one ray) to white (the cap's `n²`), at twice the scene's size, into
/// `path`. Returns a line saying what it drew.
fn ray_map(scene: &Scene, points: &[Point], quick: bool, path: &Path) -> Result<String> {
    let target = points.iter().find(|p| p.label == "jitter 8x8");
    let best = target.and_then(|j| {
        points
            .iter()
            .filter(|p| p.family.starts_with("adaptive") && reaches(p.rmse, j.rmse))
            .min_by(|a, b| a.time_ms.total_cmp(&b.time_ms))
    });
    let all = configs(quick);
    let config = best
        .and_then(|b| all.iter().find(|c| c.label == b.label))
        .or_else(|| all.iter().rev().find(|c| c.family.starts_with("adaptive")))
        .context("no adaptive setting to draw")?;
    let Sampler::Adaptive { max, .. } = config.sampler else {
        anyhow::bail!("{} is not adaptive", config.label);
    };
    let (w, h) = (scene.width, scene.height);
    let counts = scene.primary_rays_per_pixel(Rect::full(w, h), &config.sampler);
    let most = f64::from(max * max).ln().max(f64::MIN_POSITIVE);
    let grey = |c: u32| (255.0 * (f64::from(c.max(1)).ln() / most).min(1.0)).round() as u8;
    let image = image::GrayImage::from_fn(w * 2, h * 2, |x, y| {
        image::Luma([grey(counts[((y / 2) * w + x / 2) as usize])])
    });
    image
        .save(path)
        .with_context(|| format!("cannot write {}", path.display()))?;
    let mean = counts.iter().map(|&c| f64::from(c)).sum::<f64>() / counts.len().max(1) as f64;
    Ok(format!(
        "rays per pixel, {}: {mean:.1} on average, drawn in {}",
        config.label,
        path.display()
    ))
}

/// POV-Ray's renders of the scene `desc` (named `name`) with each of its anti-aliasing
/// settings ([`crate::povray::Antialias::all`]), one thread, `repeats` times each: the
/// median trace time, its own sample and ray counts, and the error against `exact`. `None`
/// where the scene cannot be translated (a texture).
fn antialiased(
    povray: &str,
    desc: &SceneDesc,
    exact: &[Color],
    repeats: usize,
    name: &str,
    dir: &Path,
) -> Result<Option<Vec<Point>>> {
    if let Err(e) = crate::povray::to_pov(desc) {
        println!("  POV-Ray skipped: {e}");
        return Ok(None);
    }
    let mut out = Vec::new();
    for aa in crate::povray::Antialias::all() {
        let mut times = Vec::with_capacity(repeats);
        let mut last = None;
        for _ in 0..repeats {
            let r = crate::povray::render_antialiased(povray, desc, aa, dir)
                .with_context(|| format!("POV-Ray on {name}, {}", aa.label()))?;
            times.push(r.time_ms);
            last = Some(r);
        }
        // `repeats` is at least 1, so the loop ran.
        let Some(r) = last else { continue };
        let (rmse, worst) = error(&r.image, exact);
        let p = Point {
            scene: name.to_string(),
            family: aa.family(),
            label: aa.label(),
            primary_per_px: r.samples_per_px,
            rays_per_px: r.rays_per_px,
            time_ms: median(times),
            rmse,
            worst,
            pareto: false,
        };
        println!(
            "  {:<26} {:>7.2} spp {:>8.2} rays/px {:>9.2} ms  RMSE {:.2e}  worst {:.3}",
            p.label, p.primary_per_px, p.rays_per_px, p.time_ms, p.rmse, p.worst
        );
        out.push(p);
    }
    Ok(Some(out))
}

/// The errors below which POV-Ray's settings are compared: where anti-aliasing is asked to
/// do its work, rather than leave edges visibly stepped.
const POVRAY_ERRORS_BELOW: f64 = 0.03;

/// The cheapest of `points` that reaches error `target` and passes `keep`.
fn cheapest_reaching(
    points: &[Point],
    target: f64,
    keep: impl Fn(&Point) -> bool,
) -> Option<&Point> {
    points
        .iter()
        .filter(|a| keep(a) && reaches(a.rmse, target))
        .min_by(|a, b| a.time_ms.total_cmp(&b.time_ms))
}

/// For each POV-Ray setting whose error is below [`POVRAY_ERRORS_BELOW`]: how long POV-Ray
/// takes against Tessera's cheapest setting that reaches its error (any sampler: what a
/// user would pick for that error), and against the cheapest adaptive one, one line each;
/// then the smallest of each ratio. `points` are Tessera's settings alone.
fn povray_vs_tessera(points: &[Point], pov: &[Point]) -> Vec<String> {
    let mut lines = Vec::new();
    let mut least: Option<f64> = None;
    let mut least_adaptive: Option<f64> = None;
    let lower = |l: &mut Option<f64>, r: f64| *l = Some(l.map_or(r, |v| v.min(r)));
    for p in pov.iter().filter(|p| p.rmse < POVRAY_ERRORS_BELOW) {
        let mut line = format!("{} RMSE {:.2e} in {:.1} ms", p.label, p.rmse, p.time_ms);
        match cheapest_reaching(points, p.rmse, |_| true) {
            Some(a) => {
                let ratio = p.time_ms / a.time_ms;
                lower(&mut least, ratio);
                let _ = write!(
                    line,
                    "; {} reaches {:.2e} in {:.1} ms: POV-Ray takes {ratio:.2}×",
                    a.label, a.rmse, a.time_ms
                );
            }
            None => line.push_str("; no setting of Tessera's reaches it"),
        }
        match cheapest_reaching(points, p.rmse, |a| a.family.starts_with("adaptive")) {
            Some(a) => {
                let ratio = p.time_ms / a.time_ms;
                lower(&mut least_adaptive, ratio);
                let _ = write!(
                    line,
                    " (adaptive: {} in {:.1} ms, {ratio:.2}×)",
                    a.label, a.time_ms
                );
            }
            None => line.push_str(" (no adaptive setting reaches it)"),
        }
        lines.push(line);
    }
    if let Some(l) = least {
        let mut line = format!(
            "POV-Ray below {POVRAY_ERRORS_BELOW} RMSE: it takes at least {l:.2}× the time of \
             Tessera's cheapest setting"
        );
        if let Some(a) = least_adaptive {
            let _ = write!(line, " ({a:.2}× adaptive's)");
        }
        lines.push(line);
    }
    lines
}

/// Jitter N×N against the cheapest adaptive setting that reaches its error, if any does.
struct Versus<'a> {
    jitter: &'a Point,
    adaptive: Option<&'a Point>,
}

impl Versus<'_> {
    /// The summary line: both errors and times, the speed-up, and, where counted, both
    /// renders' instructions (jitter's, adaptive's).
    fn line(&self, instructions: Option<(u64, u64)>) -> String {
        let j = self.jitter;
        let Some(a) = self.adaptive else {
            return format!(
                "{} RMSE {:.2e} in {:.1} ms; no adaptive setting reaches it",
                j.label, j.rmse, j.time_ms
            );
        };
        let mut line = format!(
            "{} RMSE {:.2e} in {:.1} ms; {} reaches {:.2e} in {:.1} ms: {:.2}× faster",
            j.label,
            j.rmse,
            j.time_ms,
            a.label,
            a.rmse,
            a.time_ms,
            j.time_ms / a.time_ms
        );
        if let Some((ji, ai)) = instructions {
            let _ = write!(
                line,
                "; instructions {:.1} M → {:.1} M ({:.2}×)",
                ji as f64 / 1e6,
                ai as f64 / 1e6,
                ji as f64 / (ai as f64).max(1.0)
            );
        }
        line
    }
}

/// For jitter 4×4, 6×6 and 8×8 (those the run measured): the cheapest adaptive setting
/// that reaches its error.
fn adaptive_vs_jitter(points: &[Point]) -> Vec<Versus<'_>> {
    [4, 6, 8]
        .iter()
        .filter_map(|n| {
            let label = format!("jitter {n}x{n}");
            let jitter = points.iter().find(|p| p.label == label)?;
            let adaptive = points
                .iter()
                .filter(|p| p.family.starts_with("adaptive") && reaches(p.rmse, jitter.rmse))
                .min_by(|a, b| a.time_ms.total_cmp(&b.time_ms));
            Some(Versus { jitter, adaptive })
        })
        .collect()
}

fn to_csv(points: &[Point]) -> String {
    let mut s =
        String::from("scene,family,config,primary_per_px,rays_per_px,time_ms,rmse,worst,pareto\n");
    for p in points {
        let _ = writeln!(
            s,
            "{},{},{},{:.4},{:.4},{:.4},{:.6e},{:.6},{}",
            p.scene,
            p.family,
            p.label,
            p.primary_per_px,
            p.rays_per_px,
            p.time_ms,
            p.rmse,
            p.worst,
            p.pareto
        );
    }
    s
}

fn panel(name: &str, points: &[Point], ref_err: f64) -> Panel {
    let mut families: Vec<String> = Vec::new();
    for p in points {
        if !families.contains(&p.family) {
            families.push(p.family.clone());
        }
    }
    let series = families
        .iter()
        .map(|f| {
            let mut pts: Vec<(f64, f64)> = points
                .iter()
                .filter(|p| &p.family == f)
                .map(|p| (p.time_ms, p.rmse))
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            Series {
                name: f.clone(),
                points: pts,
            }
        })
        .collect();
    let mut front: Vec<(f64, f64)> = points
        .iter()
        .filter(|p| p.pareto)
        .map(|p| (p.time_ms, p.rmse))
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    Panel {
        title: name.to_string(),
        series,
        front,
        floor: ref_err,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same error summed in another order reaches its target; an error a millionth
    /// above it does not.
    #[test]
    fn an_error_reaches_its_target_only_to_within_rounding() {
        let target = 9.015_672e-3;
        let resummed = [0.3, 0.1, 0.2].iter().sum::<f64>() / 0.6 * target;
        assert!(reaches(resummed, target) && reaches(target, target));
        assert!(!reaches(target * (1.0 + 1e-6), target));
    }

    fn p(time_ms: f64, rmse: f64) -> Point {
        Point {
            scene: "s".into(),
            family: "f".into(),
            label: "l".into(),
            primary_per_px: 1.0,
            rays_per_px: 1.0,
            time_ms,
            rmse,
            worst: 0.0,
            pareto: false,
        }
    }

    fn named(family: &str, time_ms: f64, rmse: f64) -> Point {
        Point {
            family: family.into(),
            label: format!("{family} {time_ms}"),
            ..p(time_ms, rmse)
        }
    }

    /// Each POV-Ray setting is set against the fastest setting that reaches its error,
    /// whatever its sampler, and against the fastest adaptive one; settings that miss the
    /// error are passed over however fast, and POV-Ray's settings at 0.03 or above are not
    /// compared.
    #[test]
    fn povray_meets_the_cheapest_setting_reaching_its_error() {
        let tessera = [
            named("grid", 2.0, 0.019),
            named("adaptive t=0.1", 4.0, 0.015),
            named("adaptive t=0.3", 1.0, 0.025),
            named("jitter", 8.0, 0.005),
        ];
        let pov = [
            named("POV-Ray AM1", 12.0, 0.02),
            named("POV-Ray AM2", 40.0, 0.01),
            named("POV-Ray AM1", 1.0, 0.05),
        ];
        let lines = povray_vs_tessera(&tessera, &pov);
        assert_eq!(lines.len(), 3, "{lines:?}");
        assert!(lines[0].contains("grid 2 reaches") && lines[0].contains("6.00×"));
        assert!(lines[0].contains("(adaptive: adaptive t=0.1 4 in 4.0 ms, 3.00×)"));
        assert!(lines[1].contains("jitter 8 reaches") && lines[1].contains("5.00×"));
        assert!(lines[1].contains("no adaptive setting reaches it"));
        assert!(
            lines[2].ends_with(
                "at least 5.00× the time of Tessera's cheapest setting (3.00× adaptive's)"
            ),
            "{}",
            lines[2]
        );
    }

    #[test]
    fn pareto_front_keeps_only_undominated_points() {
        let mut pts = vec![
            p(1.0, 0.5),
            p(2.0, 0.2),
            p(3.0, 0.3),
            p(4.0, 0.1),
            p(2.0, 0.2),
        ];
        mark_pareto(&mut pts);
        let front: Vec<bool> = pts.iter().map(|p| p.pareto).collect();
        // (3, 0.3) is beaten by (2, 0.2); the two equal points both stay.
        assert_eq!(front, vec![true, true, false, true, true]);
    }
}
