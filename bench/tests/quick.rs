//! The benchmarks run in their short modes, so they cannot rot: each produces its outputs and
//! its figures are sane (finite, positive, one row per scene and setting).

use std::path::PathBuf;
use std::process::Command;

fn bench() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_tessera-bench"));
    c.current_dir(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(".."));
    c
}

fn out_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("tessera-bench-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).expect("temp dir");
    d
}

#[test]
fn chart_quick_writes_a_csv_and_an_svg() {
    let out = out_dir("chart");
    let run = bench()
        .args(["chart", "--quick", "--out"])
        .arg(&out)
        .output()
        .expect("tessera-bench runs");
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let csv = std::fs::read_to_string(out.join("chart.csv")).expect("chart.csv");
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    let scenes = std::fs::read_dir(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes"))
        .expect("bench/scenes")
        .count();
    // center, thesis, and for n in {2, 4}: grid, jitter, adaptive.
    assert_eq!(rows.len(), scenes * 8, "{csv}");
    for row in rows {
        let f: Vec<&str> = row.split(',').collect();
        let nums: Vec<f64> = f[3..8]
            .iter()
            .map(|x| x.parse().expect("a number"))
            .collect();
        assert!(nums.iter().all(|x| x.is_finite() && *x >= 0.0), "{row}");
        assert!(nums[0] > 0.0 && nums[2] > 0.0 && nums[3] > 0.0, "{row}");
        // Every sampler but adaptive traces a ray or more in every pixel; adaptive traces
        // none in a blank one, so its average may fall below one.
        assert!(f[1].starts_with("adaptive") || nums[0] >= 1.0, "{row}");
    }
    assert!(csv.lines().any(|l| l.ends_with(",true")), "no Pareto point");
    let svg = std::fs::read_to_string(out.join("chart.svg")).expect("chart.svg");
    assert!(svg.starts_with("<svg") && svg.contains("Pareto front"));
    assert!(stdout.contains("jitter 4x4 RMSE"), "{stdout}");
    if valgrind_runs() {
        summary_counts_each_renders_instructions(&stdout);
    }
}

fn valgrind_runs() -> bool {
    Command::new("valgrind")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Each summary line that names an adaptive setting carries both renders' instruction
/// counts, and they count the render: jitter 4×4 traces 16 primary rays a pixel, each at
/// least its camera ray, a test against the scene and an encoding (well over 20
/// instructions), and no ray of the quick scenes takes 100,000.
fn summary_counts_each_renders_instructions(stdout: &str) {
    let mut pixels = None;
    let mut counted = 0;
    for line in stdout.lines() {
        // A scene's header: `name: W×H, reference …`.
        if let Some((w, h)) = line
            .split_once(": ")
            .and_then(|(_, rest)| rest.split_once(','))
            .and_then(|(size, _)| size.split_once('×'))
            .and_then(|(w, h)| Some((w.parse::<f64>().ok()?, h.parse::<f64>().ok()?)))
        {
            pixels = Some(w * h);
        }
        if !line.contains(" reaches ") || line.contains("no adaptive") {
            continue;
        }
        let (_, counts) = line
            .split_once("instructions ")
            .unwrap_or_else(|| panic!("no instructions in {line:?}"));
        let millions: Vec<f64> = counts
            .split(" M")
            .take(2)
            .map(|x| x.trim_start_matches(" → ").parse().expect("a count"))
            .collect();
        let rays = 16.0 * pixels.expect("a scene header before its summary");
        let per_ray = millions[0] * 1e6 / rays;
        assert!((20.0..1e5).contains(&per_ray), "{per_ray} a ray: {line}");
        assert!(millions[1] > 0.0, "{line}");
        counted += 1;
    }
    assert!(
        counted > 0,
        "no summary line names an adaptive setting:\n{stdout}"
    );
}

#[test]
fn features_quick_shows_unused_features_cost_nothing() {
    let run = bench()
        .args(["features", "--quick"])
        .output()
        .expect("runs");
    assert!(run.status.success());
    let stdout = String::from_utf8_lossy(&run.stdout);
    let row = |name: &str| -> Vec<f64> {
        let line = stdout
            .lines()
            .find(|l| l.starts_with(name))
            .unwrap_or_else(|| panic!("no row {name} in\n{stdout}"));
        line[name.len()..]
            .split_whitespace()
            .map(|x| x.parse().expect("a number"))
            .collect()
    };
    // Columns: primary, shadow, mirror rays per pixel, time.
    assert_eq!(row("one sphere, one light")[1], 0.0);
    // The ring of small spheres: their shadow rays are known clear and culled.
    assert_eq!(row("nine spheres, one light")[1], 0.0);
    assert!(row("nine spheres, no culling")[1] > 0.0);
    assert!(row("+ floor (shadows possible)")[1] > 0.0);
    assert_eq!(row("+ floor, shadow = 0")[1], 0.0);
    assert_eq!(row("+ floor, mirror 0 (written)")[2], 0.0);
    assert!(row("+ floor, mirror 0.5 sphere")[2] > 0.0);
    assert!(row("+ floor, adaptive 4x4")[0] < row("+ floor, jitter 4x4")[0]);
}

/// Runs a comparison with `args`; its table when it ran, `None` when it said `skipped`
/// (what it compares with is not installed).
fn comparison(args: &[&str], skipped: &str) -> Option<String> {
    let run = bench().args(args).output().expect("runs");
    let stdout = String::from_utf8_lossy(&run.stdout).to_string();
    assert!(
        run.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    (!stdout.contains(skipped)).then_some(stdout)
}

/// The rows of a comparison's scenes that ran, each checked for the same picture: fewer
/// than 1 % of the pixels (the last column) off by more than two steps.
fn same_pictures(stdout: &str) -> Vec<&str> {
    let rows: Vec<&str> = stdout
        .lines()
        .skip(1)
        .filter(|l| l.contains('×') && !l.contains("skipped"))
        .collect();
    for line in &rows {
        let cols: Vec<&str> = line.split_whitespace().collect();
        let off: f64 = cols[cols.len() - 1]
            .trim_end_matches('%')
            .parse()
            .expect("a share");
        assert!(off < 1.0, "images differ: {line}");
    }
    rows
}

#[test]
fn povray_comparison_runs_or_says_why_not() {
    let Some(stdout) = comparison(&["povray", "--quick", "--repeats", "1"], "povray not found")
    else {
        return;
    };
    // Two tables: one ray per pixel, then the thesis's five.
    let (one, five) = stdout
        .split_once("five rays per pixel")
        .expect("a table at five rays per pixel");
    // Same picture at one ray: the images agree closely on every scene that was translated.
    let rows = same_pictures(one);
    assert!(!rows.is_empty(), "{stdout}");
    // At five rays POV-Ray places its rays where the thesis does (the centre and ±1/4
    // pixel) but averages before it clamps, where Tessera clamps each ray: the images
    // differ only where a pixel straddles an over-bright surface and its neighbour, a small
    // share of the pixels, so the mean difference stays a fraction of one step.
    let five_rows: Vec<&str> = five.lines().filter(|l| l.contains('×')).collect();
    assert_eq!(five_rows.len(), rows.len(), "{stdout}");
    for line in five_rows {
        let cols: Vec<&str> = line.split_whitespace().collect();
        let mean: f64 = cols[cols.len() - 2].parse().expect("a mean");
        let rays: f64 = cols[cols.len() - 3]
            .parse()
            .expect("POV-Ray's rays per pixel");
        assert!(mean < 0.5, "images differ: {line}");
        assert!(
            (4.9..5.3).contains(&rays),
            "POV-Ray's rays per pixel: {line}"
        );
    }
}

#[test]
fn embree_comparison_runs_or_says_why_not() {
    let Some(stdout) = comparison(&["embree", "--quick"], "the Embree reference is skipped") else {
        return;
    };
    // Every scene of spheres and planes is traced (the thin rods are not), to the same
    // picture but for a few mirror pixels.
    assert!(same_pictures(&stdout).len() >= 5, "{stdout}");
    assert!(stdout.contains("skipped: a cylinder"), "{stdout}");
}

#[test]
fn tracer_quick_reports_rates_and_the_bvh_scaling() {
    let run = bench().args(["tracer", "--quick"]).output().expect("runs");
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let scenes = std::fs::read_dir(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes"))
        .expect("bench/scenes")
        .count();
    // One line per bench scene, with a positive rate in the last column.
    let rates: Vec<f64> = stdout
        .lines()
        .skip(2)
        .take(scenes)
        .map(|l| {
            l.split_whitespace()
                .last()
                .and_then(|x| x.parse().ok())
                .unwrap_or_else(|| panic!("no rate in {l:?}\n{stdout}"))
        })
        .collect();
    assert!(rates.iter().all(|r| r.is_finite() && *r > 0.0), "{stdout}");
    // Two scaling tables, the cloud then the layer: N, build ms, peak and kept bytes per
    // sphere, rays, ns/ray, ratio, the same without tables, linear ns/ray, linear/BVH.
    let lines: Vec<&str> = stdout.lines().collect();
    let starts: Vec<usize> = (0..lines.len())
        .filter(|&i| lines[i].starts_with("BVH scaling"))
        .collect();
    assert_eq!(starts.len(), 2, "{stdout}");
    assert!(lines[starts[0]].contains("(cloud)") && lines[starts[1]].contains("(layer)"));
    for &start in &starts {
        let rows: Vec<Vec<&str>> = lines[start + 2..]
            .iter()
            .take_while(|l| !l.starts_with("per-ray"))
            .map(|l| l.split_whitespace().collect())
            .collect();
        assert_eq!(rows.len(), 3, "{stdout}");
        for r in &rows {
            let build: f64 = r[1].parse().expect("build ms");
            let ns: f64 = r[5].parse().expect("ns/ray");
            assert!(build.is_finite() && build >= 0.0, "{stdout}");
            assert!(ns.is_finite() && ns > 0.0, "{stdout}");
            // Bytes per sphere, where the process says its memory.
            assert!(
                r[2..4]
                    .iter()
                    .all(|b| *b == "-" || b.parse::<u64>().is_ok()),
                "{stdout}"
            );
        }
    }
    assert_eq!(stdout.matches("that at N=16 in the").count(), 2, "{stdout}");
}

#[test]
fn farm_quick_reports_overhead_scaling_queue_and_memory() {
    let run = bench()
        .args(["farm", "--quick"])
        .env("RUST_LOG", "error")
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    // The farm's PNG is compared byte for byte with the local render's.
    assert!(stdout.contains("PNG identical: yes"), "{stdout}");
    for part in ["overhead (", "scaling (", "queue (", "memory:"] {
        assert!(stdout.contains(part), "no {part} line in\n{stdout}");
    }
    // The service's threads are read from /proc: at least the 4×4 job renders long enough
    // for its render threads to count clock ticks, and the shares are percentages.
    if cfg!(target_os = "linux") {
        let shares: Vec<f64> = stdout
            .lines()
            .filter_map(|l| l.split_once("render threads': ")?.1.split(" %").next())
            .map(|x| x.parse().expect("a share"))
            .collect();
        assert!(!shares.is_empty(), "no service CPU line in\n{stdout}");
        assert!(shares.iter().all(|s| (0.0..1000.0).contains(s)), "{stdout}");
    }
    let per_s: f64 = stdout
        .lines()
        .find(|l| l.contains("claims+results/s"))
        .and_then(|l| l.split(": ").last())
        .and_then(|x| x.split_whitespace().next())
        .and_then(|x| x.parse().ok())
        .unwrap_or_else(|| panic!("no queue rate in\n{stdout}"));
    assert!(per_s.is_finite() && per_s > 0.0, "{stdout}");
}

#[test]
fn farm_quick_measures_the_queue_on_both_databases() {
    let run = bench()
        .args(["farm", "--quick", "--parts", "queue"])
        .output()
        .expect("runs");
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    // One line per queue, each with a positive rate (the PostgreSQL ones on the tests'
    // throwaway server, which `.ci/run` installs).
    for label in [
        "queue (SQLite)",
        "queue (PostgreSQL, one replica)",
        "queue (PostgreSQL, two replicas)",
    ] {
        let line = stdout
            .lines()
            .find(|l| l.contains(label))
            .unwrap_or_else(|| panic!("no `{label}` line in:\n{stdout}"));
        let rate: f64 = line
            .split(" claims+results/s")
            .next()
            .and_then(|s| s.rsplit(' ').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("no rate in `{line}`"));
        assert!(rate > 0.0 && rate.is_finite(), "{line}");
    }
}
