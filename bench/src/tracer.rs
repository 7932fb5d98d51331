//! The tracer's own speed, one thread: rays per second on each bench scene, and how the
//! per-ray cost grows with the number of objects, with the BVH and without it.
//!
//! The scaling scenes are `N` random, non-overlapping small spheres (one per cell of a
//! jittered grid, fixed seed) over a ground plane, lit by one light with shadows, so every
//! ray is a nearest-hit query and most hits add an any-hit shadow query. They come in two
//! layouts ([`Layout`]): a *cloud* filling a cube, where a ray that misses crosses about
//! `∛N` cells of spheres (so no search can be logarithmic in it), and a *layer* facing the
//! camera, where every ray crosses the spheres once and meets only its own neighbourhood
//! (the case in which a BVH's cost grows with `log N`). Time per ray is the
//! median render time over all rays traced (primary and shadow). Wall-clock figures on a
//! shared machine are noisy; `valgrind --tool=callgrind` on this subcommand gives repeatable
//! instruction counts for A/B comparisons.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use tessera_tracer::{
    Acceleration, DirAssets, Limits, MemoryAssets, RayStats, Rect, Scene, TextureLimits,
};

use crate::stats::Spread;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Bench scenes (`.ray` files or directories of them); by default the chart's
    /// scenes and `bench/scenes-perf` (CSG), which only the speed comparisons use.
    #[arg(long, default_values = ["bench/scenes", "bench/scenes-perf"])]
    scenes: Vec<PathBuf>,
    /// Small images, fewer sizes, one repeat (for CI: a few seconds).
    #[arg(long)]
    quick: bool,
    /// Timed runs of each render; the median is reported.
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// Only the bench scenes, no scaling table (for profiling one scene under callgrind).
    #[arg(long)]
    scenes_only: bool,
    /// Sphere counts for the scaling table (default: 4 to 16,384 and 1,000,000; quick: 16,
    /// 256, 4096).
    #[arg(long, value_delimiter = ',')]
    sizes: Vec<usize>,
    /// Only this scaling table: the sphere cloud or the sphere layer (default: both).
    #[arg(long, value_enum)]
    layout: Option<Layout>,
    /// Also write each scaling scene to this folder (`cloud-N.ray`, `layer-N.ray`), to look at
    /// or to render elsewhere.
    #[arg(long)]
    write_scenes: Option<PathBuf>,
    /// Leave out the linear (no BVH) column of the scaling table.
    #[arg(long)]
    no_linear: bool,
    /// How the bench scenes find candidate objects (the scaling table shows both).
    #[arg(long, value_enum, default_value_t = Accel::Auto)]
    acceleration: Accel,
}

/// [`Acceleration`] as a command-line value.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum Accel {
    Auto,
    Off,
    Always,
}

impl From<Accel> for Acceleration {
    fn from(a: Accel) -> Acceleration {
        match a {
            Accel::Auto => Acceleration::Auto,
            Accel::Off => Acceleration::Off,
            Accel::Always => Acceleration::Always,
        }
    }
}

/// Where the scaling scenes put their spheres.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Layout {
    /// Filling the cube [-10, 10]³: sparser as `N` grows, so a ray crosses about `∛N` cells.
    Cloud,
    /// In a slab facing the camera (the square [-10, 10]² in x and y, a cell deep in z):
    /// every ray crosses it once and meets only the spheres near its crossing.
    Layer,
}

impl Layout {
    /// The name in the table's title and in `--write-scenes` file names.
    fn name(self) -> &'static str {
        match self {
            Layout::Cloud => "cloud",
            Layout::Layer => "layer",
        }
    }
}

/// SplitMix64, so the scaling scenes are the same on every run.
struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// `n` spheres over a plane at y = -11, each inside its own cell of a grid (so none overlap),
/// the cells chosen at random (fixed seed).
///
/// - [`Layout::Cloud`]: cells of a `k³` grid over the cube [-10, 10]³ (`k³ ≥ n`).
/// - [`Layout::Layer`]: cells of a `k²` grid over the square [-10, 10]² in x and y
///   (`k² ≥ n`), each sphere at a random depth within a cell's width of z = 0.
///
/// Radii shrink as `1/√n` (from about 1.5 at n = 16 to 0.05 at 16384 in the cloud), so the
/// spheres' total cross-section, and so the share of rays that hit one, is about the same at
/// every `n`: the per-ray cost then compares the search for the nearest hit, not a different
/// mix of shaded hits and cheap misses.
pub fn spheres_scene(layout: Layout, n: usize, width: u32, height: u32) -> String {
    let dims = match layout {
        Layout::Cloud => 3,
        Layout::Layer => 2,
    };
    let k = (1..).find(|k: &usize| k.pow(dims) >= n).unwrap_or(1);
    let cell = 20.0 / k as f64;
    let mut rng = Rng(0x7e55_e7a0 + n as u64);
    // Choose n distinct cells: a partial Fisher–Yates shuffle of all cell indices.
    let mut cells: Vec<usize> = (0..k.pow(dims)).collect();
    for i in 0..n {
        let j = i + ((rng.unit() * (cells.len() - i) as f64) as usize).min(cells.len() - i - 1);
        cells.swap(i, j);
    }
    let eye = match layout {
        Layout::Cloud => "<6, 8, 40>",
        Layout::Layer => "<2, 3, 40>",
    };
    let mut s = format!(
        "[GLOBALS]\nwidth = {width}\nheight = {height}\nambient = 0.15\nshadow = 0.8\n\
         background = <0.1, 0.1, 0.2>\n[/GLOBALS]\n\
         [CAMERA]\neye = {eye}\nlook_at = <0, -2, 0>\nfov = 40\n[/CAMERA]\n\
         [LIGHT]\nposition = <30, 60, 40>\n[/LIGHT]\n\
         [OBJECT]\ntype = plane\ntranslate = <0, -11, 0>\ncolor1 = 0.7\ncolor2 = 0.4\n[/OBJECT]\n"
    );
    for &c in &cells[..n] {
        // Both layouts: at most 0.45 of a cell, so a sphere stays inside its own cell.
        let r = match layout {
            // 7.5/√n at most: below half a cell (10/∛n) for every n ≥ 1.
            Layout::Cloud => 6.0 / (n as f64).sqrt() * (0.75 + 0.5 * rng.unit()),
            // A third of a cell on average: about a third of the square is covered.
            Layout::Layer => 0.33 * cell * (0.75 + 0.5 * rng.unit()),
        }
        .min(0.45 * cell);
        let slack = cell / 2.0 - r;
        let at = |i: usize, u: f64| -10.0 + (i as f64 + 0.5) * cell + slack * (2.0 * u - 1.0);
        let (px, py, pz) = match layout {
            Layout::Cloud => {
                let (x, y, z) = (c % k, (c / k) % k, c / (k * k));
                (at(x, rng.unit()), at(y, rng.unit()), at(z, rng.unit()))
            }
            Layout::Layer => {
                let (x, y) = (c % k, c / k);
                (
                    at(x, rng.unit()),
                    at(y, rng.unit()),
                    cell * (rng.unit() - 0.5),
                )
            }
        };
        s += &format!(
            "[OBJECT]\ntype = sphere\nradius = {r:.6}\ntranslate = <{px:.6}, {py:.6}, {pz:.6}>\n\
             color1 = <{:.3}, {:.3}, {:.3}>\n[/OBJECT]\n",
            0.3 + 0.7 * rng.unit(),
            0.3 + 0.7 * rng.unit(),
            0.3 + 0.7 * rng.unit()
        );
    }
    s
}

/// Median seconds of rendering `rect` on this thread, and the rays it took.
/// The process's resident memory now and its peak since it was last reset, in bytes, from
/// `/proc/self/status` (Linux).
#[derive(Debug, Clone, Copy)]
struct Memory {
    resident: u64,
    peak: u64,
}

impl Memory {
    /// Resets the peak to the resident memory now (`/proc/self/clear_refs`), so that the
    /// next reading's peak is that of what follows, and reads both; `None` where the peak
    /// cannot be reset.
    fn reset_peak() -> Option<Memory> {
        std::fs::write("/proc/self/clear_refs", "5").ok()?;
        Memory::read()
    }

    /// `None` where `/proc` does not say.
    fn read() -> Option<Memory> {
        let status = std::fs::read_to_string("/proc/self/status").ok()?;
        let field = |name: &str| {
            status
                .lines()
                .find_map(|l| l.strip_prefix(name))?
                .split_whitespace()
                .next()?
                .parse::<u64>()
                .ok()
                .map(|kb| kb * 1024)
        };
        Some(Memory {
            resident: field("VmRSS:")?,
            peak: field("VmHWM:")?,
        })
    }
}

fn time_render(scene: &Scene, rect: Rect, repeats: usize) -> (f64, RayStats) {
    let mut times = Vec::with_capacity(repeats);
    let mut stats = RayStats::default();
    for _ in 0..repeats.max(1) {
        let start = Instant::now();
        let (_, s) = scene.render_rect_linear(rect);
        times.push(start.elapsed().as_secs_f64());
        stats = s;
    }
    times.sort_by(f64::total_cmp);
    (times[times.len() / 2], stats)
}

fn load(path: &Path) -> Result<Scene> {
    let src = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    Scene::from_source(
        &src,
        &Limits::default(),
        &DirAssets::new(dir),
        &TextureLimits::default(),
    )
    .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

pub fn run(args: &Args) -> Result<()> {
    let repeats = if args.quick { 1 } else { args.repeats };
    if args.sizes.is_empty() {
        scenes(args, repeats)?;
    }
    if args.scenes_only {
        return Ok(());
    }
    if let Some(dir) = &args.write_scenes {
        std::fs::create_dir_all(dir).with_context(|| format!("{}", dir.display()))?;
    }
    let layouts = match args.layout {
        Some(one) => vec![one],
        None => vec![Layout::Cloud, Layout::Layer],
    };
    for layout in layouts {
        scaling(args, layout, repeats)?;
    }
    if args.layout.is_none() && args.sizes.is_empty() {
        csg_union(args, repeats)?;
    }
    Ok(())
}

/// The cloud's spheres as one flat CSG union: per-ray cost with the tree's child index
/// (see `tessera_tracer::csg`), with the plain loop over its children, and of the same
/// spheres as separate objects (the scene's BVH), so that the table shows what the index
/// gains and what a union still costs over separate objects. The images with and without
/// the index are compared byte for byte.
fn csg_union(args: &Args, repeats: usize) -> Result<()> {
    let (w, h) = if args.quick { (48, 36) } else { (160, 120) };
    let sizes: &[usize] = if args.quick {
        &[16, 256]
    } else {
        &[16, 256, 1024, 4096, 16384]
    };
    // The loop's cost grows with N per ray: measured once, and only up to here.
    let loop_up_to = if args.quick { 256 } else { 4096 };
    println!();
    println!("CSG union of the cloud's N spheres (one [CSG] op = union), {w}x{h}, one thread:");
    println!(
        "{:>6} {:>10} {:>14} {:>12} {:>11} {:>15} {:>10}",
        "N", "rays", "indexed ns/ray", "loop ns/ray", "loop/index", "objects ns/ray", "union/obj"
    );
    for &n in sizes {
        let objects = spheres_scene(Layout::Cloud, n, w, h);
        // The plane comes first, then the spheres: wrap the spheres.
        let first = objects
            .find("[OBJECT]\ntype = sphere")
            .context("the cloud scene has no sphere")?;
        let union = format!(
            "{}[CSG]\nop = union\n{}[/CSG]\n",
            &objects[..first],
            &objects[first..]
        );
        let build = |src: &str| {
            Scene::from_source(
                src,
                &Limits::default(),
                &MemoryAssets::new(),
                &TextureLimits::default(),
            )
            .map_err(|e| anyhow::anyhow!("{n} spheres: {e}"))
        };
        let full = Rect::full(w, h);
        let indexed = build(&union)?;
        let (secs, stats) = time_render(&indexed, full, repeats);
        let ns = secs * 1e9 / stats.total() as f64;
        let (plain, gain) = if n <= loop_up_to {
            let plain = indexed.clone().without_acceleration();
            let (lsecs, lstats) = time_render(&plain, full, 1);
            anyhow::ensure!(
                plain.render_rect_linear(full).0 == indexed.render_rect_linear(full).0,
                "{n} spheres: the union's image differs with and without its index"
            );
            let lns = lsecs * 1e9 / lstats.total() as f64;
            (format!("{lns:.0}"), format!("{:.1}", lns / ns))
        } else {
            ("-".to_string(), "-".to_string())
        };
        let (osecs, ostats) = time_render(&build(&objects)?, full, repeats);
        let ons = osecs * 1e9 / ostats.total() as f64;
        println!(
            "{n:>6} {:>10} {ns:>14.0} {plain:>12} {gain:>11} {ons:>15.0} {:>10.1}",
            stats.total(),
            ns / ons
        );
    }
    Ok(())
}

/// Rays per second on each bench scene.
fn scenes(args: &Args, repeats: usize) -> Result<()> {
    println!("Bench scenes, one thread (median of {repeats}):");
    println!(
        "{:<18} {:>9} {:>5} {:>10} {:>12}",
        "scene", "size", "bvh", "rays", "Mrays/s"
    );
    for path in crate::scenes::scene_files(&args.scenes)? {
        let scene = load(&path)?.with_acceleration(args.acceleration.into());
        // Quick: the middle of the image, a quarter each way (a few milliseconds).
        let rect = if args.quick {
            let (w, h) = ((scene.width / 4).max(1), (scene.height / 4).max(1));
            Rect::new((scene.width - w) / 2, (scene.height - h) / 2, w, h)
        } else {
            Rect::full(scene.width, scene.height)
        };
        let (secs, stats) = time_render(&scene, rect, repeats);
        let name = path.file_stem().map(|s| s.to_string_lossy().into_owned());
        println!(
            "{:<18} {:>9} {:>5} {:>10} {:>12.3}",
            name.unwrap_or_default(),
            format!("{}x{}", rect.width, rect.height),
            if scene.uses_bvh() { "yes" } else { "no" },
            stats.total(),
            stats.total() as f64 / secs / 1e6
        );
    }

    Ok(())
}

/// The BVH scaling table.
fn scaling(args: &Args, layout: Layout, repeats: usize) -> Result<()> {
    let (w, h) = if args.quick { (48, 36) } else { (160, 120) };
    let sizes: &[usize] = if !args.sizes.is_empty() {
        &args.sizes
    } else if args.quick {
        &[16, 256, 4096]
    } else {
        &[4, 8, 16, 64, 256, 1024, 4096, 16384, 1_000_000]
    };
    let linear_at: &[usize] = if args.quick {
        &[16, 256]
    } else {
        &[4, 8, 16, 1024]
    };
    println!();
    let name = layout.name();
    println!("BVH scaling ({name}): N random spheres + ground plane, {w}x{h}, one thread:");
    println!(
        "{:>9} {:>9} {:>11} {:>11} {:>10} {:>12} {:>8} {:>15} {:>8} {:>14} {:>11}",
        "N",
        "build ms",
        "peak B/obj",
        "kept B/obj",
        "rays",
        "BVH ns/ray",
        "× N=16",
        "no tables ns/ray",
        "× N=16",
        "linear ns/ray",
        "linear/BVH"
    );
    let (mut at16, mut plain16) = (None, None);
    // The scene at N = 16 and the last one after it, for the headline pairs.
    let (mut small, mut large): (Option<Scene>, Option<(usize, Scene)>) = (None, None);
    for &n in sizes {
        let src = spheres_scene(layout, n, w, h);
        if let Some(dir) = &args.write_scenes {
            let path = dir.join(format!("{name}-{n}.ray"));
            std::fs::write(&path, &src).with_context(|| format!("{}", path.display()))?;
        }
        // The plane is one object more than the spheres: a million spheres take the
        // limit of one more than the default's.
        let limits = Limits {
            max_objects: Limits::default().max_objects.max(n + 1),
            ..Limits::default()
        };
        // What parsing and building take, the scene's text aside: time, the peak of the
        // process's resident memory above what it held before, and what the scene keeps.
        let before = Memory::reset_peak();
        let started = Instant::now();
        let scene = Scene::from_source(
            &src,
            &limits,
            &MemoryAssets::new(),
            &TextureLimits::default(),
        )
        .map_err(|e| anyhow::anyhow!("{n} spheres: {e}"))?
        .with_acceleration(Acceleration::Always);
        let build_ms = started.elapsed().as_secs_f64() * 1e3;
        let after = Memory::read();
        let per_object = |bytes: Option<u64>| {
            bytes.map_or("-".to_string(), |b| format!("{:.0}", b as f64 / n as f64))
        };
        let peak = per_object(
            before
                .zip(after)
                .map(|(b, a)| a.peak.saturating_sub(b.resident)),
        );
        let kept = per_object(
            before
                .zip(after)
                .map(|(b, a)| a.resident.saturating_sub(b.resident)),
        );
        let full = Rect::full(w, h);
        let (secs, stats) = time_render(&scene, full, repeats);
        let ns = secs * 1e9 / stats.total() as f64;
        // The same BVH with every ray walking it: what the eye's and the lights' tables
        // (tessera_tracer::point_index) save.
        let plain = scene.clone().without_point_tables();
        let (psecs, pstats) = time_render(&plain, full, repeats);
        let pns = psecs * 1e9 / pstats.total() as f64;
        if n == 16 {
            at16 = Some(ns);
            plain16 = Some(pns);
        }
        let ratio = at16.map_or("-".to_string(), |b| format!("{:.2}", ns / b));
        let pratio = plain16.map_or("-".to_string(), |b| format!("{:.2}", pns / b));
        let (lin, gain) = if !args.no_linear && linear_at.contains(&n) {
            let lin = scene.clone().without_acceleration();
            let (lsecs, lstats) = time_render(&lin, full, repeats);
            let lns = lsecs * 1e9 / lstats.total() as f64;
            (format!("{lns:.0}"), format!("{:.2}", lns / ns))
        } else {
            ("-".to_string(), "-".to_string())
        };
        println!(
            "{n:>9} {build_ms:>9.1} {peak:>11} {kept:>11} {:>10} {ns:>12.0} {ratio:>8} {pns:>15.0} {pratio:>8} {lin:>14} {gain:>11}",
            stats.total()
        );
        // The headline pair: N = 16 against 16,384 where the table has it, else its last.
        if n == 16 {
            small = Some(scene);
        } else if small.is_some() && large.as_ref().is_none_or(|(m, _)| *m != 16_384) {
            large = Some((n, scene));
        }
    }
    if let (Some(small), Some((n, large))) = (small, large) {
        // The headline figure as back-to-back pairs (one render of each, alternately): the
        // large scene's cost depends on how much of the shared cache the host's other work
        // leaves it, and a pair sees the same host.
        let full = Rect::full(w, h);
        let pairs = if args.quick { 1 } else { 9 };
        let pair_ratios = |small: &Scene, large: &Scene| {
            let ratios: Vec<f64> = (0..pairs)
                .map(|_| {
                    let (a, sa) = time_render(small, full, 1);
                    let (b, sb) = time_render(large, full, 1);
                    (b / sb.total() as f64) / (a / sa.total() as f64)
                })
                .collect();
            Spread::of(ratios)
        };
        let r = pair_ratios(&small, &large);
        println!(
            "per-ray cost at N={n} is {:.2}× that at N=16 in the {name} (median of {} back-to-back pairs, {:.2}–{:.2}; target: within 3×)",
            r.median, r.count, r.lo, r.hi
        );
        let p = pair_ratios(&small.without_point_tables(), &large.without_point_tables());
        println!(
            "  without the eye's and the lights' tables (every ray walks the BVH): {:.2}× ({:.2}–{:.2})",
            p.median, p.lo, p.hi
        );
    }
    Ok(())
}
