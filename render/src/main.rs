//! `tessera-render`: the stand-alone tracer. Renders a `.ray` scene to a PNG on this machine,
//! on all cores (or `--threads N`), with no service involved.
//!
//! This crate is only the command line: flags, the progress bar, reading the scene and
//! writing the file, and errors reported as `file:line:col: message`. Parsing, rendering and
//! PNG encoding are the `tessera-tracer` library's, which is why that library needs none of
//! clap, indicatif or anyhow. Install it with `cargo install --path render`.

use std::fs::{File, OpenOptions};
use std::io::{BufWriter, IsTerminal, Read, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use tessera_tracer::{
    DirAssets, Limits, MAX_SCENE_FILE_BYTES, MAX_THREADS, PngWriter, Scene, SceneError,
    TextureLimits, local_tile, parse, scene_text,
};

/// The output file, shared with the PNG encoder. The encoder owns its writer and gives no
/// way back to it, and a `BufWriter` dropped with bytes in it flushes them and ignores the
/// error: a full disk would leave a cut-short PNG and a render that says it succeeded. With a
/// handle kept here, the last bytes are flushed where a failure is an error.
#[derive(Clone)]
struct OutFile(Arc<Mutex<BufWriter<File>>>);

impl OutFile {
    fn lock(&self) -> MutexGuard<'_, BufWriter<File>> {
        // Held for one write or flush at a time, neither of which panics; a poisoned lock
        // still guards a whole writer.
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl Write for OutFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.lock().write(buf)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.lock().flush()
    }
}

/// Render a .ray scene to a PNG.
#[derive(Debug, Parser)]
#[command(name = "tessera-render", version, about)]
struct Args {
    /// The scene file (`-`: standard input). Texture names in it are resolved relative to
    /// its directory (the current one for `-`).
    scene: PathBuf,

    /// Where to write the PNG.
    #[arg(short, long, default_value = "out.png")]
    output: PathBuf,

    /// Worker threads, 1 to 1024 (default: one per core).
    #[arg(long, env = "TESSERA_THREADS",
          value_parser = clap::value_parser!(u16).range(1..=i64::from(MAX_THREADS)))]
    threads: Option<u16>,

    /// Override the scene's sampler: center, thesis, grid, jitter or adaptive.
    #[arg(long, ignore_case = true,
          value_parser = ["center", "thesis", "grid", "jitter", "adaptive"])]
    sampler: Option<String>,

    /// Samples per axis for grid, jitter and adaptive (N × N per pixel at most).
    #[arg(long)]
    samples: Option<u32>,

    /// Contrast threshold for the adaptive sampler.
    #[arg(long)]
    threshold: Option<f64>,

    /// No progress bar or summary.
    #[arg(short, long)]
    quiet: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            if let Some(scene_err) = e.downcast_ref::<SceneError>() {
                eprintln!("{}", scene_err.with_file(&scene_name(&args.scene)));
            } else {
                eprintln!("tessera-render: {e:#}");
            }
            ExitCode::FAILURE
        }
    }
}

/// The scene file's bytes, at most [`MAX_SCENE_FILE_BYTES`] of them. Any readable file is
/// taken, a pipe included (`<(generate-scene)`), but not read past the cap.
fn read_scene(path: &Path) -> Result<Vec<u8>> {
    let what = || format!("cannot read {}", scene_name(path));
    let mut bytes = Vec::new();
    if is_stdin(path) {
        std::io::stdin()
            .lock()
            .take(MAX_SCENE_FILE_BYTES + 1)
            .read_to_end(&mut bytes)
            .with_context(what)?;
    } else {
        File::open(path)
            .with_context(what)?
            .take(MAX_SCENE_FILE_BYTES + 1)
            .read_to_end(&mut bytes)
            .with_context(what)?;
    }
    if bytes.len() as u64 > MAX_SCENE_FILE_BYTES {
        anyhow::bail!(
            "{} is larger than {} MiB, the most a scene file may have: is it a scene?",
            scene_name(path),
            MAX_SCENE_FILE_BYTES >> 20
        );
    }
    Ok(bytes)
}

/// Whether the scene is read from standard input (`-`, as Unix tools take it).
fn is_stdin(path: &Path) -> bool {
    path == Path::new("-")
}

/// The scene as messages name it: its path, or `<stdin>`.
fn scene_name(path: &Path) -> String {
    if is_stdin(path) {
        "<stdin>".to_string()
    } else {
        path.display().to_string()
    }
}

/// Fails now if the PNG could not be written at the end, so that a mistyped `-o` does not
/// cost the render: a directory, a missing folder, a file that may not be written, the
/// scene file itself. A path
/// that does not exist is created to prove it can be and removed again; an existing file is
/// opened for writing, not truncated, so that it is kept if the render fails. Devices and
/// pipes are left alone (opening a pipe waits for its reader).
/// Whether two paths name one existing file: through links, `.` and `..`, and (on Unix,
/// by device and inode) a hard link.
fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        matches!(
            (std::fs::metadata(a), std::fs::metadata(b)),
            (Ok(x), Ok(y)) if x.dev() == y.dev() && x.ino() == y.ino()
        )
    }
    #[cfg(not(unix))]
    {
        matches!(
            (std::fs::canonicalize(a), std::fs::canonicalize(b)),
            (Ok(x), Ok(y)) if x == y
        )
    }
}

fn check_output(path: &Path, scene: &Path) -> Result<()> {
    let what = || format!("cannot create {}", path.display());
    // `-o` naming the scene itself replaced the scene with its picture.
    if !is_stdin(scene) && same_file(path, scene) {
        anyhow::bail!(
            "cannot create {}: it is the scene file being rendered",
            path.display()
        );
    }
    match std::fs::metadata(path) {
        Ok(meta) if meta.is_dir() => {
            anyhow::bail!("cannot create {}: it is a directory", path.display())
        }
        Ok(meta) if meta.is_file() => {
            OpenOptions::new()
                .write(true)
                .open(path)
                .with_context(what)?;
        }
        Ok(_) => {}
        // A link to nothing yet: the PNG is written through it at the end, like any path.
        Err(_) if std::fs::symlink_metadata(path).is_ok() => {}
        Err(_) => {
            OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(path)
                .with_context(what)?;
            // The file just made is empty; the real one is written after the render.
            std::fs::remove_file(path).with_context(what)?;
        }
    }
    Ok(())
}

fn run(args: &Args) -> Result<()> {
    let source = scene_text(read_scene(&args.scene)?)?;
    let limits = Limits::default();
    let mut desc = parse(&source, &limits)?;
    desc.sampler = desc
        .sampler
        .with_overrides(
            args.sampler.as_deref(),
            args.samples,
            args.threshold,
            limits.max_samples,
        )
        .map_err(anyhow::Error::msg)?;
    let dir = args.scene.parent().unwrap_or(Path::new("."));
    let assets = DirAssets::new(dir);
    check_output(&args.output, &args.scene)?;
    // Nor one of the scene's textures, which it replaced with the render.
    if let Some((name, _)) = desc
        .texture_names()
        .into_iter()
        .find(|(name, _)| same_file(&args.output, &assets.path_of(name)))
    {
        anyhow::bail!(
            "cannot create {}: it is the scene's texture `{name}`",
            args.output.display()
        );
    }
    let scene = Scene::build(&desc, &assets, &TextureLimits::default())?;

    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(n) = args.threads {
        pool = pool.num_threads(usize::from(n));
    }
    let pool = pool.build().context("cannot start the thread pool")?;

    let total = u64::from(scene.width) * u64::from(scene.height);
    let bar = if args.quiet || !std::io::stderr().is_terminal() {
        ProgressBar::hidden()
    } else {
        let bar = ProgressBar::new(total);
        bar.set_style(
            ProgressStyle::with_template("{bar:40} {percent:>3}% {elapsed} (eta {eta})")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar
    };
    let start = Instant::now();
    let tile = local_tile(scene.width, scene.height, pool.current_num_threads());
    let (rgb, stats) = pool.install(|| scene.render_image(tile, |done| bar.set_position(done)));
    bar.finish_and_clear();
    let elapsed = start.elapsed();

    let file = std::fs::File::create(&args.output)
        .with_context(|| format!("cannot create {}", args.output.display()))?;
    let out = OutFile(Arc::new(Mutex::new(BufWriter::new(file))));
    let mut png = PngWriter::new(out.clone(), scene.width, scene.height)?;
    png.write_rows(&rgb)
        .and_then(|()| png.finish())
        .map_err(anyhow::Error::from)
        .and_then(|()| Ok(out.lock().flush()?))
        .with_context(|| format!("cannot write {}", args.output.display()))?;

    if !args.quiet {
        let rays = stats.total() as f64;
        let threads = pool.current_num_threads();
        eprintln!(
            "{}: {}×{} in {:.3} s on {threads} thread{}, {:.2} rays/pixel, {:.2} Mrays/s",
            args.output.display(),
            scene.width,
            scene.height,
            elapsed.as_secs_f64(),
            if threads == 1 { "" } else { "s" },
            rays / total as f64,
            rays / elapsed.as_secs_f64() / 1e6
        );
    }
    Ok(())
}
