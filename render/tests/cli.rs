//! `tessera-render` as a user runs it: a PNG out, errors as `file:line:col: message`.

use std::path::{Path, PathBuf};
use std::process::Command;

use tessera_tracer::{DirAssets, Limits, Scene, TextureLimits, encode_png};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera-render"))
}

/// `tessera-render SCENE -o OUTPUT`, run to its end.
fn render_to(scene: &Path, output: &Path) -> std::process::Output {
    bin()
        .arg(scene)
        .arg("-o")
        .arg(output)
        .output()
        .expect("runs")
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

/// Renders `scene` into `dir`, expecting a refusal: returns what it printed.
fn refused(scene: &Path, dir: &Path) -> String {
    let out = render_to(scene, &dir.join("x.png"));
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
    // `.` and `..` are resolved in the name, as the farm resolves them: `maps/` need not
    // exist (it failed with "No such file or directory" while the farm rendered the scene).
    let lit = |name: &str| {
        format!(
            "[GLOBALS]\nwidth = 4\nheight = 4\nambient = 1\n[/GLOBALS]\n\
             [OBJECT]\ntype = sphere\nradius = 30\ntexture = {name}\n[/OBJECT]\n"
        )
    };
    // `-o` naming one of the scene's textures replaced it with the render.
    std::fs::write(&scene, lit("maps/../t.ppm")).expect("write");
    let out = render_to(&scene, &dir.join("t.ppm"));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("it is the scene's texture `maps/../t.ppm`"),
        "{stderr}"
    );
    assert!(
        std::fs::read(dir.join("t.ppm"))
            .expect("kept")
            .starts_with(b"P3")
    );
    for name in ["./t.ppm", "maps/../t.ppm", "a/./b/../../t.ppm"] {
        std::fs::write(&scene, lit(name)).expect("write");
        let out = bin()
            .arg(&scene)
            .arg("-o")
            .arg(&png)
            .arg("-q")
            .output()
            .expect("runs");
        assert!(
            out.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let img = image::open(&png).expect("a PNG").into_rgb8();
        assert_eq!(img.get_pixel(2, 2).0, [255, 0, 0], "{name}");
    }

    std::fs::write(
        &scene,
        "[OBJECT]\ntype = sphere\ntexture = missing.ppm\n[/OBJECT]\n",
    )
    .expect("write");
    let out = render_to(&scene, &png);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(":3:11: ") && stderr.contains("missing.ppm"),
        "{stderr}"
    );
}

/// A PNG that cannot be written whole is an error, not a success with a cut-short file:
/// `/dev/full` takes nothing (`ENOSPC` on every write), like a full disk. A small image is
/// the case to check: all of it sits in the output buffer until the end.
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
    // The cause once: `{:#}` prints it twice when the PNG error also holds it as a source.
    assert!(
        stderr.contains("cannot write /dev/full") && stderr.matches("No space left").count() == 1,
        "{stderr}"
    );
}

/// A texture name that names a device is refused at once, at the name's position: reading
/// `/dev/zero` would run until memory ran out.
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

/// A texture name that resolves to the scene's own folder (`.`, `maps/..`) says so: the
/// file system would otherwise be asked for an empty path ("cannot read texture file `.`: :
/// No such file or directory").
#[test]
fn a_texture_naming_the_scenes_folder_says_so() {
    let dir = temp_dir("folder-texture");
    std::fs::create_dir_all(dir.join("maps")).expect("maps");
    for name in [".", "maps/.."] {
        let scene = dir.join("s.ray");
        std::fs::write(
            &scene,
            format!("[OBJECT]\ntype = sphere\ntexture = {name}\n[/OBJECT]\n"),
        )
        .expect("write");
        let stderr = refused(&scene, &dir);
        assert!(
            stderr.contains(&format!("{}:3:11: ", scene.display()))
                && stderr.contains("names the scene's own folder, not a file"),
            "{name}: {stderr}"
        );
    }
}

/// Runs `cmd` to its end, or fails the test if it has not ended within `limit`: for the
/// cases below, which run for ever unless refused (a render of hours, a read of `/dev/zero`,
/// an open of a pipe). A guard against a hang, not a measure of speed: the cases take well
/// under a second.
fn output_within(cmd: &mut Command, limit: std::time::Duration) -> std::process::Output {
    use std::process::Stdio;
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("runs");
    let start = std::time::Instant::now();
    loop {
        if child.try_wait().expect("wait").is_some() {
            return child.wait_with_output().expect("output");
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("still running after {limit:?}");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// A scene that would take hours: its output path is checked before the render, so that a
/// mistyped `-o` fails at once instead of after the render (a directory, a missing folder).
/// An existing file is not truncated by the check, and a path the check creates is removed.
#[test]
fn an_output_that_cannot_be_written_fails_before_the_render() {
    let dir = temp_dir("output");
    let scene = dir.join("slow.ray");
    std::fs::write(
        &scene,
        "[GLOBALS]\nwidth = 16384\nheight = 16384\nsampler = jitter\nsamples = 32\n[/GLOBALS]\n\
         [OBJECT]\ntype = sphere\n[/OBJECT]\n",
    )
    .expect("write");
    let limit = std::time::Duration::from_secs(60);
    for (output, expected) in [
        (dir.join("missing").join("x.png"), "No such file"),
        (dir.clone(), "it is a directory"),
    ] {
        let out = output_within(bin().arg(&scene).arg("-o").arg(&output).arg("-q"), limit);
        assert!(!out.status.success());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            stderr.contains(&format!("cannot create {}", output.display()))
                && stderr.contains(expected),
            "{stderr}"
        );
    }
    // A writable path passes the check (made before the textures are loaded) and leaves
    // nothing behind when the scene then fails to build; an existing file keeps its bytes.
    let bad = dir.join("bad.ray");
    std::fs::write(
        &bad,
        "[OBJECT]\ntype = sphere\ntexture = none.png\n[/OBJECT]\n",
    )
    .expect("write");
    let fresh = dir.join("fresh.png");
    let kept = dir.join("kept.png");
    std::fs::write(&kept, b"old image").expect("write");
    for output in [&fresh, &kept] {
        assert!(!render_to(&bad, output).status.success());
    }
    assert!(!fresh.exists());
    assert_eq!(std::fs::read(&kept).expect("kept"), b"old image");
    // `-o` naming the scene would replace the scene with its picture: refused, here through `.`
    // and (Unix) through a hard link, where the paths have nothing in common.
    let refused_as_the_scene = |output: &Path| {
        let out = render_to(&bad, output);
        assert!(!out.status.success());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(stderr.contains("it is the scene file"), "{stderr}");
        let kept = std::fs::read_to_string(&bad).expect("kept");
        assert!(kept.starts_with("[OBJECT]"));
    };
    refused_as_the_scene(&dir.join(".").join("bad.ray"));
    #[cfg(unix)]
    {
        let twin = dir.join("twin.png");
        std::fs::hard_link(&bad, &twin).expect("a hard link");
        refused_as_the_scene(&twin);
    }
    // A link to a file not yet there is written through: the check refuses only the scene.
    #[cfg(unix)]
    {
        let target = dir.join("target.png");
        let link = dir.join("link.png");
        let _ = std::fs::remove_file(&target);
        let _ = std::fs::remove_file(&link);
        std::os::unix::fs::symlink(&target, &link).expect("symlink");
        let out = bin()
            .arg(examples().join("thesis.ray"))
            .arg("-o")
            .arg(&link)
            .args(["-q", "--threads", "1"])
            .output()
            .expect("runs");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(image::open(&target).is_ok());
    }
}

/// A scene path that never ends (`/dev/zero`) is read up to the cap and refused, instead of
/// until memory runs out.
#[test]
fn a_scene_file_is_read_only_up_to_its_cap() {
    if !Path::new("/dev/zero").exists() {
        eprintln!("skipped: no /dev/zero here");
        return;
    }
    let limit = std::time::Duration::from_secs(60);
    let out = output_within(bin().args(["/dev/zero", "-q"]), limit);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    let cap = tessera_tracer::MAX_SCENE_FILE_BYTES >> 20;
    assert!(
        stderr.contains(&format!("/dev/zero is larger than {cap} MiB")),
        "{stderr}"
    );
}

/// A texture name that names a pipe is refused at once: opening a pipe waits for a writer,
/// and the render waited for ever.
#[test]
fn a_texture_that_is_a_pipe_is_refused() {
    let dir = temp_dir("fifo");
    let fifo = dir.join("pipe.png");
    let _ = std::fs::remove_file(&fifo);
    match Command::new("mkfifo").arg(&fifo).status() {
        Ok(s) if s.success() => {}
        _ => {
            eprintln!("skipped: no mkfifo here");
            return;
        }
    }
    let scene = dir.join("s.ray");
    std::fs::write(
        &scene,
        "[OBJECT]\ntype = sphere\ntexture = pipe.png\n[/OBJECT]\n",
    )
    .expect("write");
    let limit = std::time::Duration::from_secs(60);
    let out = output_within(bin().arg(&scene).arg("-o").arg(dir.join("x.png")), limit);
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(&format!("{}:3:11: ", scene.display()))
            && stderr.contains("pipe.png: not a regular file"),
        "{stderr}"
    );
}

/// `-` reads the scene from standard input, as Unix tools do: the same image as from the
/// file (textures from the current folder), and errors named `<stdin>:line:col`.
#[test]
fn a_scene_from_standard_input() {
    use std::io::Write;
    use std::process::Stdio;
    let dir = temp_dir("stdin");
    let render = |stdin: &[u8], out: &Path| {
        let mut child = bin()
            .current_dir(examples())
            .args(["-", "-q", "-o"])
            .arg(out)
            .stdin(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("runs");
        child
            .stdin
            .take()
            .expect("piped")
            .write_all(stdin)
            .expect("write");
        child.wait_with_output().expect("ends")
    };
    let scene = std::fs::read(examples().join("textures.ray")).expect("scene");
    let piped = render(&scene, &dir.join("piped.png"));
    assert!(piped.status.success(), "{piped:?}");
    let file = bin()
        .arg(examples().join("textures.ray"))
        .args(["-q", "-o"])
        .arg(dir.join("file.png"))
        .output()
        .expect("runs");
    assert!(file.status.success(), "{file:?}");
    assert!(
        std::fs::read(dir.join("piped.png")).expect("png")
            == std::fs::read(dir.join("file.png")).expect("png")
    );
    let bad = render(b"[GLOBALS]\nwidht = 3\n[/GLOBALS]\n", &dir.join("bad.png"));
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert_eq!(bad.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("<stdin>:2:1: unknown key `widht`"),
        "{stderr}"
    );
}
