//! What a scene pays for each feature: the same scene with and without shadows, mirrors,
//! textures, more lights and more objects (with and without the culling of shadow rays that
//! nothing can block), in rays per pixel and time. The point it makes:
//! a feature a scene does not use costs no rays, and the adaptive sampler spends samples only
//! where the image varies.

use std::time::Instant;

use anyhow::Result;
use tessera_tracer::{Limits, MemoryAssets, Scene, TextureLimits, tiles};

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Smaller images and one repeat (for CI).
    #[arg(long)]
    quick: bool,
}

/// A scene from parts: the sphere's extra keys, whether a floor plane is present, the number
/// of lights and the globals' extra keys.
fn scene_text(size: (u32, u32), sphere: &str, floor: bool, lights: u32, globals: &str) -> String {
    let mut s = format!(
        "[GLOBALS]\nwidth = {}\nheight = {}\nambient = 0.1\nbackground = <0.3, 0.4, 0.6>\n{globals}\n[/GLOBALS]\n\
         [CAMERA]\neye = <0, 3, 12>\nlook_at = <0, 1, 0>\nfov = 45\n[/CAMERA]\n",
        size.0, size.1
    );
    for i in 0..lights {
        let a = f64::from(i) * 1.7;
        s += &format!(
            "[LIGHT]\nposition = <{:.2}, 12, {:.2}>\ncolor = {:.3}\n[/LIGHT]\n",
            8.0 * a.cos(),
            8.0 * a.sin(),
            1.0 / f64::from(lights)
        );
    }
    s += &format!(
        "[OBJECT]\ntype = sphere\nradius = 1.5\ntranslate = <0, 1.5, 0>\n{sphere}\n[/OBJECT]\n"
    );
    if floor {
        s += "[OBJECT]\ntype = plane\ncolor1 = 0.8\ncolor2 = 0.3\n[/OBJECT]\n";
    }
    s
}

fn texture() -> MemoryAssets {
    let mut ppm = b"P6\n64 32\n255\n".to_vec();
    for y in 0..32u32 {
        for x in 0..64u32 {
            ppm.extend_from_slice(&[(x * 4) as u8, (y * 8) as u8, ((x ^ y) * 4) as u8]);
        }
    }
    let mut a = MemoryAssets::new();
    a.insert("t.ppm", ppm);
    a
}

/// The one variant rendered with every shadow ray traced (the culling's reference).
const NO_CULLING: &str = "nine spheres, no culling";

pub fn run(args: &Args) -> Result<()> {
    let (size, repeats) = if args.quick {
        ((80, 60), 1)
    } else {
        ((320, 240), 9)
    };
    // Eight small spheres around the big one, none in the way of another's light: every
    // shadow ray from them is known to be clear (see `tessera_tracer::shadow`).
    let ring: String = (0..8)
        .map(|i| {
            let a = f64::from(i) * std::f64::consts::FRAC_PI_4;
            format!(
                "[OBJECT]\ntype = sphere\nradius = 0.5\ntranslate = <{:.3}, 0.5, {:.3}>\n[/OBJECT]\n",
                4.0 * a.cos(),
                4.0 * a.sin()
            )
        })
        .collect();
    let nine = scene_text(size, "", false, 1, "") + &ring;
    let variants: Vec<(&str, String)> = vec![
        ("one sphere, one light", scene_text(size, "", false, 1, "")),
        ("nine spheres, one light", nine.clone()),
        (NO_CULLING, nine),
        (
            "+ floor (shadows possible)",
            scene_text(size, "", true, 1, ""),
        ),
        (
            "+ floor, shadow = 0",
            scene_text(size, "", true, 1, "shadow = 0"),
        ),
        ("+ floor, 4 lights", scene_text(size, "", true, 4, "")),
        (
            "+ floor, mirror 0.5 sphere",
            scene_text(size, "mirror = 0.5", true, 1, ""),
        ),
        (
            "+ floor, mirror 0 (written)",
            scene_text(size, "mirror = 0", true, 1, ""),
        ),
        (
            "+ floor, textured sphere",
            scene_text(size, "texture = t.ppm", true, 1, ""),
        ),
        (
            "+ floor, jitter 4x4",
            scene_text(size, "", true, 1, "sampler = jitter\nsamples = 4"),
        ),
        (
            "+ floor, adaptive 4x4",
            scene_text(size, "", true, 1, "sampler = adaptive\nsamples = 4"),
        ),
    ];
    let assets = texture();
    let mut scenes = Vec::with_capacity(variants.len());
    for (name, src) in &variants {
        let scene = Scene::from_source(src, &Limits::default(), &assets, &TextureLimits::default())
            .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        scenes.push(if *name == NO_CULLING {
            scene.without_shadow_culling()
        } else {
            scene
        });
    }
    // Repeats go round the variants, as the chart's do, so that a burst of load elsewhere
    // spreads over all of them rather than landing on one variant's runs.
    let mut times = vec![Vec::with_capacity(repeats); scenes.len()];
    let mut stats = vec![tessera_tracer::RayStats::default(); scenes.len()];
    for _ in 0..repeats {
        for (i, scene) in scenes.iter().enumerate() {
            let mut total = tessera_tracer::RayStats::default();
            let start = Instant::now();
            for r in tiles(scene.width, scene.height, 32) {
                let (_, s) = scene.render_rect_linear_with(r, &scene.sampler);
                total.add(&s);
            }
            times[i].push(start.elapsed().as_secs_f64() * 1e3);
            stats[i] = total;
        }
    }
    println!(
        "{:<30} {:>9} {:>9} {:>9} {:>10}",
        "scene", "primary", "shadow", "mirror", "time (ms)"
    );
    for (((name, _), scene), (t, st)) in variants
        .iter()
        .zip(&scenes)
        .zip(times.into_iter().zip(&stats))
    {
        let px = f64::from(scene.width * scene.height);
        println!(
            "{name:<30} {:>9.2} {:>9.2} {:>9.2} {:>10.2}",
            st.primary as f64 / px,
            st.shadow as f64 / px,
            st.mirror as f64 / px,
            crate::stats::median(t)
        );
    }
    println!("(rays per pixel; time is one thread, median of {repeats})");
    Ok(())
}
