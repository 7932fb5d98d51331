//! `tessera-render` as a user runs it: a PNG out, errors as `file:line:col: message`.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use tessera_tracer::{DirAssets, Limits, Scene, TextureLimits, encode_png};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera-render"))
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("tessera-cli-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

/// Every example renders, and the PNG is byte-identical to the library's own render.
#[test]
fn examples_render_to_the_same_png_as_the_library() {
    let dir = temp_dir("examples");
    let mut rendered = 0;
    for entry in std::fs::read_dir(examples()).expect("examples/") {
        let path = entry.expect("entry").path();
        if path.extension().is_none_or(|e| e != "ray") {
            continue;
        }
        let out = dir
            .join(path.file_stem().expect("a name"))
            .with_extension("png");
        let status = bin()
            .arg(&path)
            .arg("-o")
            .arg(&out)
            .args(["--threads", "2", "--quiet"])
            .status()
            .expect("tessera-render runs");
        assert!(status.success(), "{}", path.display());
        let src = std::fs::read_to_string(&path).expect("scene");
        let assets = DirAssets::new(examples());
        let scene =
            Scene::from_source(&src, &Limits::default(), &assets, &TextureLimits::default())
                .expect("example parses");
        let (rgb, _) = scene.render_image(16, |_| {});
        let png = encode_png(scene.width, scene.height, &rgb).expect("encode");
        assert!(
            std::fs::read(&out).expect("output") == png,
            "{}: CLI and library differ",
            path.display()
        );
        rendered += 1;
    }
    assert!(rendered >= 3, "only {rendered} examples");
}

/// Renders `scene` into `dir`, expecting a refusal: returns what was printed.
fn refused(scene: &Path, dir: &Path) -> String {
    let out = bin()
        .arg(scene)
        .arg("-o")
        .arg(dir.join("x.png"))
        .output()
        .expect("runs");
    assert!(!out.status.success());
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn scene_errors_are_printed_as_file_line_col_and_fail() {
    let dir = temp_dir("errors");
    let scene = dir.join("bad.ray");
    std::fs::write(
        &scene,
        "[GLOBALS]\nwidht = 3\n[/GLOBALS]\n[OBJECT]\ntype = sphere\nradius = -1\n[/OBJECT]\n",
    )
    .expect("write");
    let stderr = refused(&scene, &dir);
    let lines: Vec<&str> = stderr.lines().collect();
    let name = scene.display().to_string();
    assert_eq!(lines.len(), 2, "{stderr}");
    assert!(lines[0].starts_with(&format!("{name}:2:1: ")), "{stderr}");
    assert!(lines[0].contains("did you mean `width`"), "{stderr}");
    assert!(lines[1].starts_with(&format!("{name}:6:10: ")), "{stderr}");
    assert!(!dir.join("x.png").exists(), "no image for a bad scene");
}

#[test]
fn a_scene_that_is_not_text_is_refused_at_its_first_bad_byte() {
    let dir = temp_dir("binary");
    let scene = dir.join("latin1.ray");
    // "# caf" then 0xe9 (é in Latin-1, not UTF-8) on line 2, after 5 characters.
    std::fs::write(&scene, b"[GLOBALS]\n# caf\xe9\n[/GLOBALS]\n").expect("write");
    let stderr = refused(&scene, &dir);
    let name = scene.display().to_string();
    assert!(
        stderr.starts_with(&format!("{name}:2:6: not UTF-8 text (byte 0xe9)")),
        "{stderr}"
    );
}

#[test]
fn missing_files_and_bad_flags_fail_with_a_message() {
    let out = bin().arg("/nonexistent/scene.ray").output().expect("runs");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot read /nonexistent/scene.ray"));
    let out = bin()
        .arg(examples().join("thesis.ray"))
        .args(["--threads", "0"])
        .output()
        .expect("runs");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--threads"));
    // Past the bound: refused before a thread starts (100,000 threads ran past any timeout).
    let over = (tessera_tracer::MAX_THREADS + 1).to_string();
    let out = bin()
        .arg(examples().join("thesis.ray"))
        .args(["--threads", &over])
        .env_remove("TESSERA_THREADS")
        .output()
        .expect("runs");
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("--threads") && stderr.contains("1..=1024"),
        "{stderr}"
    );
}

#[test]
fn texture_names_resolve_next_to_the_scene_and_errors_point_at_them() {
    let dir = temp_dir("textures");
    std::fs::write(dir.join("t.ppm"), b"P3\n1 1\n255\n255 0 0\n").expect("write");
    let scene = dir.join("s.ray");
    std::fs::write(
        &scene,
        "[GLOBALS]\nwidth = 4\nheight = 4\nambient = 1\n[/GLOBALS]\n\
         [OBJECT]\ntype = sphere\nradius = 30\ntexture = t.ppm\n[/OBJECT]\n",
    )
    .expect("write");
    let png = dir.join("s.png");
    let status = bin()
        .arg(&scene)
        .arg("-o")
        .arg(&png)
        .arg("-q")
        .status()
        .expect("runs");
    assert!(status.success());
    let img = image::open(&png).expect("a PNG").into_rgb8();
    assert_eq!(img.get_pixel(2, 2).0, [255, 0, 0]);

    std::fs::write(
        &scene,
        "[OBJECT]\ntype = sphere\ntexture = missing.ppm\n[/OBJECT]\n",
    )
    .expect("write");
    let out = bin()
        .arg(&scene)
        .arg("-o")
        .arg(&png)
        .output()
        .expect("runs");
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(":3:11: ") && stderr.contains("missing.ppm"),
        "{stderr}"
    );
}

/// A PNG that cannot be written whole is an error, not a success with a cut-short file:
/// `/dev/full` takes nothing (`ENOSPC` on every write), like a full disk. A small image is
/// the case that was missed: all of it sat in the output buffer until the end.
#[test]
fn a_full_disk_is_an_error() {
    if !Path::new("/dev/full").exists() {
        eprintln!("skipped: no /dev/full here");
        return;
    }
    let out = bin()
        .arg(examples().join("thesis.ray"))
        .args(["-o", "/dev/full", "--quiet", "--threads", "1"])
        .output()
        .expect("runs");
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("cannot write /dev/full") && stderr.contains("No space left"),
        "{stderr}"
    );
}

/// A texture name that names a device is refused at once (`/dev/zero` was read until memory
/// ran out), at the name's position.
#[test]
fn a_texture_that_is_not_a_file_is_refused() {
    if !Path::new("/dev/zero").exists() {
        eprintln!("skipped: no /dev/zero here");
        return;
    }
    let dir = temp_dir("device");
    let scene = dir.join("s.ray");
    std::fs::write(
        &scene,
        "[OBJECT]\ntype = sphere\ntexture = /dev/zero\n[/OBJECT]\n",
    )
    .expect("write");
    let stderr = refused(&scene, &dir);
    assert!(
        stderr.contains(&format!("{}:3:11: ", scene.display()))
            && stderr.contains("/dev/zero: not a regular file"),
        "{stderr}"
    );
}
