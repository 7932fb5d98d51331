//! A bounded fuzz run of the scene parser and scene builder, run in every `cargo test`:
//! arbitrary bytes, and mutations of real scenes (the inputs that get deep into the parser),
//! must give a scene or a positioned error: never a panic, and never a large allocation.
//! The case count is fixed so CI time stays bounded.

use proptest::prelude::*;
use tessera_tracer::{Limits, MemoryAssets, Scene, TextureLimits, parse};

const SEEDS: &[&str] = &[
    include_str!("../../examples/thesis.ray"),
    include_str!("../../examples/csg.ray"),
    include_str!("../../examples/shapes.ray"),
    include_str!("../../examples/camera.ray"),
    include_str!("../../examples/lights.ray"),
];

/// Small limits, so that a mutated `width = 99999999` is refused rather than rendered.
fn limits() -> Limits {
    Limits {
        max_dimension: 256,
        max_pixels: 256 * 256,
        max_objects: 64,
        max_csg_depth: 8,
        ..Limits::default()
    }
}

fn check(src: &str) {
    match parse(src, &limits()) {
        Ok(desc) => {
            assert!(desc.width <= 256 && desc.height <= 256);
            // Building must not panic either (textures are missing: a positioned error).
            let _ = Scene::build(&desc, &MemoryAssets::new(), &TextureLimits::default());
        }
        Err(e) => {
            let lines = src.lines().count().max(1) as u32 + 1;
            for d in e.diagnostics() {
                assert!(
                    d.pos.line >= 1 && d.pos.line <= lines,
                    "{d:?} in {lines} lines"
                );
                assert!(!d.message.is_empty());
            }
        }
    }
}

/// Replaces, inserts or deletes characters of a real scene at hash-chosen places.
fn mutate(seed: &str, edits: &[(usize, u8, u8)]) -> String {
    const ALPHABET: &[u8] =
        b"[]=<>,.-+0123456789eE \n\t#\"/abcdefghijklmnopqrstuvwxyzOBJECTCSGLIGHT";
    let mut bytes = seed.as_bytes().to_vec();
    for &(at, kind, c) in edits {
        if bytes.is_empty() {
            break;
        }
        let i = at % bytes.len();
        let c = ALPHABET[c as usize % ALPHABET.len()];
        match kind % 3 {
            0 => bytes[i] = c,
            1 => bytes.insert(i, c),
            _ => {
                bytes.remove(i);
            }
        }
    }
    String::from_utf8_lossy(&bytes).into_owned()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1500, max_shrink_iters: 200, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_text_never_panics(src in "\\PC{0,400}") {
        check(&src);
    }

    #[test]
    fn tag_soup_never_panics(parts in proptest::collection::vec(prop_oneof![
        Just("[GLOBALS]\n"), Just("[/GLOBALS]\n"), Just("[OBJECT]\n"), Just("[/OBJECT]\n"),
        Just("[CSG]\n"), Just("[/CSG]\n"), Just("[LIGHT]\n"), Just("[CAMERA]\n"),
        Just("type = sphere\n"), Just("type = torus\n"), Just("op = difference\n"),
        Just("width = 1e9\n"), Just("radius = -0\n"), Just("scale = <0, 1, 1>\n"),
        Just("rotate = <1e308, 0, 0>\n"), Just("color1 = <nan, 1, 1>\n"), Just("= = =\n"),
        Just("translate = <1, 2\n"), Just("minor = 2\nmajor = 1\n"), Just("\u{feff}\r\n"),
    ], 0..40)) {
        check(&parts.concat());
    }

    #[test]
    fn mutated_real_scenes_never_panic(
        which in 0..SEEDS.len(),
        edits in proptest::collection::vec((any::<usize>(), any::<u8>(), any::<u8>()), 1..12),
    ) {
        check(&mutate(SEEDS[which], &edits));
    }
}
