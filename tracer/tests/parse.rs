//! The `.ray` parser at its edges: thesis files unchanged, every kind of error with its
//! position and message, several errors reported together, and the limits.

use glam::DVec3;
use tessera_tracer::{CsgOp, Limits, Node, Pos, Sampler, SceneDesc, SceneError, Shape, parse};

fn ok(src: &str) -> SceneDesc {
    match parse(src, &Limits::default()) {
        Ok(d) => d,
        Err(e) => panic!("unexpected errors:\n{e}"),
    }
}

fn errors(src: &str) -> Vec<(u32, u32, String)> {
    errors_with(src, &Limits::default())
}

fn errors_with(src: &str, limits: &Limits) -> Vec<(u32, u32, String)> {
    match parse(src, limits) {
        Ok(_) => panic!("expected an error for:\n{src}"),
        Err(e) => e
            .diagnostics()
            .iter()
            .map(|d| (d.pos.line, d.pos.column, d.message.clone()))
            .collect(),
    }
}

/// Asserts exactly one error, at `line:col`, whose message contains every fragment.
#[track_caller]
fn one_error(src: &str, line: u32, col: u32, fragments: &[&str]) {
    let errs = errors(src);
    assert_eq!(errs.len(), 1, "expected one error, got {errs:?}");
    let (l, c, msg) = &errs[0];
    assert_eq!((*l, *c), (line, col), "position of {msg:?}");
    for f in fragments {
        assert!(msg.contains(f), "{msg:?} lacks {f:?}");
    }
}

#[test]
fn a_thesis_file_parses_unchanged() {
    let src = "\
[rayfile]
[GLOBAL]
light=<50,50,100>
[/GLOBAL]
[OBJECT]
type=sphere
radius=5.25
color1=<1,0,0>
color2=<0,0,1>
reflection=0.5
scale=<1,1,1>
rotate=<0,0,0>
translate=<10,-10,10>
[/OBJECT]
[/rayfile]
";
    let d = ok(src);
    assert_eq!(d.lights.len(), 1);
    assert_eq!(d.lights[0].position, DVec3::new(50.0, 50.0, 100.0));
    assert_eq!(d.lights[0].color, DVec3::ONE);
    let Node::Object(o) = &d.objects[0] else {
        panic!("an object")
    };
    assert_eq!(o.shape, Shape::Sphere);
    assert_eq!(o.own_scale, DVec3::splat(5.25));
    assert_eq!(o.material.mirror, 0.5);
    assert_eq!(o.material.color2, Some(DVec3::new(0.0, 0.0, 1.0)));
    // The unit sphere's top ends up at (10, -10 + 5.25, 10).
    let top = o.transform.to_world().transform_point3(DVec3::Y);
    assert!((top - DVec3::new(10.0, -4.75, 10.0)).length() < 1e-12);
}

#[test]
fn defaults_are_those_of_the_format() {
    let d = ok("");
    assert_eq!((d.width, d.height), (640, 480));
    assert_eq!(d.ambient, DVec3::splat(0.1));
    assert_eq!(d.shadow, 1.0);
    assert_eq!(d.background, DVec3::ZERO);
    assert_eq!(d.max_depth, 5);
    assert_eq!(d.sampler, Sampler::Center);
    assert_eq!(d.camera.eye, DVec3::new(0.0, 0.0, 100.0));
    assert_eq!(d.camera.look_at, DVec3::ZERO);
    assert_eq!(d.camera.up, DVec3::Y);
    assert_eq!(d.camera.fov_degrees, 30.0);
    assert!(d.lights.is_empty() && d.objects.is_empty());
}

#[test]
fn tags_keys_and_flags_are_case_insensitive_and_spacing_is_free() {
    let d = ok(
        "[Globals]\n  WIDTH=10\nHeight   =   20\nAntiAlias = YES\n[/GLOBALS]\n\
                [object]\nTYPE = Plane\n[/Object]\n",
    );
    assert_eq!((d.width, d.height), (10, 20));
    assert_eq!(d.sampler, Sampler::Thesis);
    assert!(matches!(&d.objects[0], Node::Object(o) if o.shape == Shape::Plane));
}

#[test]
fn every_key_of_the_format_is_accepted() {
    let d = ok("\
[GLOBALS]
width = 32
height = 24
ambient = <0.1, 0.2, 0.3>
shadow = 0.5
background = 0.25
max_depth = 3
sampler = adaptive
samples = 6
threshold = 0.1
light = <0, 10, 0>
[/GLOBALS]
[CAMERA]
eye = <1, 2, 3>
look_at = <0, 1, 0>
up = <0, 0, 1>
fov = 45
[/CAMERA]
[LIGHT]
position = <1, 1, 1>
color = <2, 2, 2>
[/LIGHT]
[OBJECT]
type = plane
color1 = 0.5
texture = \"wood floor.png\"
mirror = 0.25
diffuse = 0.75
[/OBJECT]
");
    assert_eq!(d.ambient, DVec3::new(0.1, 0.2, 0.3));
    assert_eq!(d.shadow, 0.5);
    assert_eq!(d.background, DVec3::splat(0.25));
    assert_eq!(d.max_depth, 3);
    assert_eq!(
        d.sampler,
        Sampler::Adaptive {
            max: 6,
            threshold: 0.1
        }
    );
    assert_eq!(d.lights.len(), 2, "the globals' light and the [LIGHT]");
    assert_eq!(d.lights[1].color, DVec3::splat(2.0));
    assert_eq!(d.camera.fov_degrees, 45.0);
    assert_eq!(
        d.texture_names(),
        vec![("wood floor.png", Pos::new(26, 11))]
    );
    let Node::Object(o) = &d.objects[0] else {
        panic!("an object")
    };
    assert_eq!((o.material.mirror, o.material.diffuse), (0.25, 0.75));
}

#[test]
fn transforms_apply_in_written_order_after_the_radius() {
    let d =
        ok("[OBJECT]\ntype = sphere\ntranslate = <10, 0, 0>\nradius = 2\nscale = 3\n[/OBJECT]\n");
    let Node::Object(o) = &d.objects[0] else {
        panic!("an object")
    };
    // radius 2 first (whatever its line), then translate, then scale: x = (1·2 + 10)·3.
    let p = o.transform.to_world().transform_point3(DVec3::X);
    assert!((p - DVec3::new(36.0, 0.0, 0.0)).length() < 1e-12, "{p:?}");
}

#[test]
fn comments_and_quoted_names_with_hashes() {
    let d = ok("[OBJECT] # a comment\ntype = plane # another\ntexture = \"a#b.ppm\"\n[/OBJECT]\n");
    assert_eq!(d.texture_names()[0].0, "a#b.ppm");
}

#[test]
fn unknown_tag_suggests_the_closest() {
    one_error(
        "[OBJCT]\ntype = sphere\n[/OBJCT]\n",
        1,
        1,
        &["unknown tag", "[OBJECT]"],
    );
}

#[test]
fn unknown_key_suggests_the_closest() {
    one_error(
        "[OBJECT]\ntype = sphere\ncolour1 = 1\n[/OBJECT]\n",
        3,
        1,
        &["colour1", "did you mean `color1`"],
    );
    one_error(
        "[GLOBALS]\n  widht = 3\n[/GLOBALS]\n",
        2,
        3,
        &["did you mean `width`"],
    );
}

#[test]
fn a_key_in_the_wrong_block_says_where_it_belongs() {
    one_error(
        "[OBJECT]\ntype = sphere\nfov = 40\n[/OBJECT]\n",
        3,
        1,
        &["fov", "[CAMERA]"],
    );
    one_error("width = 3\n", 1, 1, &["outside every block", "[GLOBALS]"]);
}

#[test]
fn duplicated_keys_are_errors_but_transforms_may_repeat() {
    one_error(
        "[OBJECT]\ntype = sphere\nradius = 1\nradius = 2\n[/OBJECT]\n",
        4,
        1,
        &["twice", "line 3"],
    );
    // `reflection` is the thesis's name for `mirror`: both at once is a duplicate.
    one_error(
        "[OBJECT]\ntype = sphere\nmirror = 0.5\nreflection = 0.5\n[/OBJECT]\n",
        4,
        1,
        &["`reflection` repeats `mirror` (line 3)"],
    );
    ok(
        "[OBJECT]\ntype = sphere\nscale = 2\nscale = 3\nrotate = <0,0,1>\nrotate = <1,0,0>\n[/OBJECT]\n",
    );
}

#[test]
fn wrong_value_types_name_what_was_expected() {
    one_error(
        "[GLOBALS]\nwidth = wide\n[/GLOBALS]\n",
        2,
        9,
        &["expected a whole number"],
    );
    one_error(
        "[LIGHT]\nposition = 1, 2, 3\n[/LIGHT]\n",
        2,
        12,
        &["expected a vector like <1, 0, 0>"],
    );
    one_error(
        "[OBJECT]\ntype = sphere\ncolor1 = red\n[/OBJECT]\n",
        3,
        10,
        &["expected a colour"],
    );
    one_error(
        "[GLOBALS]\nantialias = maybe\n[/GLOBALS]\n",
        2,
        13,
        &["on, off, yes, no, true or false"],
    );
    one_error(
        "[OBJECT]\ntype = blob\n[/OBJECT]\n",
        2,
        8,
        &["unknown type `blob`", "sphere"],
    );
    one_error(
        "[OBJECT]\ntype = sphear\n[/OBJECT]\n",
        2,
        8,
        &["did you mean `sphere`"],
    );
}

/// An extreme scale after a rotation leaves the stored inverse as accurate as the scale
/// alone does, so it is accepted; a scale that collapses an axis after a rotation is still
/// refused at the step that collapses it.
#[test]
fn a_rotation_then_an_extreme_scale_is_judged_by_its_conditioning() {
    let d =
        ok("[OBJECT]\ntype = sphere\nrotate = <10, 20, 30>\nscale = <1e4, 1e-4, 1>\n[/OBJECT]\n");
    assert_eq!(d.objects.len(), 1);
    // 1e-15 to the 21st is below the smallest normal f64 and its inverse overflows: the
    // matrix is singular in f64, refused at the 21st scale, line 24.
    one_error(
        &format!(
            "[OBJECT]\ntype = sphere\nrotate = <10, 20, 30>\n{}[/OBJECT]\n",
            "scale = <1e-15, 1, 1>\n".repeat(21)
        ),
        24,
        1,
        &["singular or non-finite"],
    );
}

#[test]
fn a_bad_vector_component_is_pointed_at() {
    //                       col 12 is '<'; the second component starts at col 16.
    one_error(
        "[LIGHT]\nposition = <1, x, 3>\n[/LIGHT]\n",
        2,
        16,
        &["component 2"],
    );
    one_error(
        "[LIGHT]\nposition = <1, 2>\n[/LIGHT]\n",
        2,
        12,
        &["three components", "found 2"],
    );
    // Finite and of determinant 1, but too ill-conditioned for its inverse to be one: the
    // message said "singular or non-finite" only.
    one_error(
        "[OBJECT]\ntype = sphere\nscale = <1e15, 1e-15, 1>\nrotate = <30, 40, 50>\n\
         scale = <1e-15, 1e15, 1>\n[/OBJECT]\n",
        5,
        1,
        &["too close to singular"],
    );
    // Nothing between the brackets is no component (it read "found 1").
    one_error(
        "[LIGHT]\nposition = <>\n[/LIGHT]\n",
        2,
        12,
        &["three components", "found 0"],
    );
    // Why the count is off, where it does not show: spaces for commas, a comma at the end.
    one_error(
        "[LIGHT]\nposition = <1 2 3>\n[/LIGHT]\n",
        2,
        12,
        &["found 1 (components are separated by commas)"],
    );
    one_error(
        "[LIGHT]\nposition = <1, 2, 3,>\n[/LIGHT]\n",
        2,
        12,
        &["found 4 (the last is empty: a comma at the end?)"],
    );
}

#[test]
fn non_finite_numbers_are_refused() {
    for bad in ["inf", "NaN", "infinity", "1e400", "-1e999"] {
        let errs = errors(&format!("[GLOBALS]\nshadow = {bad}\n[/GLOBALS]\n"));
        assert_eq!(errs.len(), 1, "{bad}");
        assert!(errs[0].2.contains("expected a number"), "{bad}: {errs:?}");
    }
}

#[test]
fn values_out_of_range_are_errors() {
    let cases = [
        ("[GLOBALS]\nshadow = 1.5\n[/GLOBALS]\n", "from 0 to 1"),
        ("[GLOBALS]\nwidth = 0\n[/GLOBALS]\n", "whole number from 1"),
        (
            "[GLOBALS]\nmax_depth = -1\n[/GLOBALS]\n",
            "whole number from 0",
        ),
        (
            "[GLOBALS]\nambient = <0.1, -0.1, 0>\n[/GLOBALS]\n",
            "components ≥ 0",
        ),
        ("[CAMERA]\nfov = 180\n[/CAMERA]\n", "between 0 and 180"),
        (
            "[OBJECT]\ntype = sphere\nradius = 0\n[/OBJECT]\n",
            "greater than 0",
        ),
        (
            "[OBJECT]\ntype = sphere\nmirror = 2\n[/OBJECT]\n",
            "from 0 to 1",
        ),
        ("[OBJECT]\ntype = sphere\ndiffuse = -1\n[/OBJECT]\n", "≥ 0"),
        (
            "[OBJECT]\ntype = sphere\nscale = <1, 0, 1>\n[/OBJECT]\n",
            "no zero component",
        ),
        (
            "[GLOBALS]\nsamples = 0\nsampler = grid\n[/GLOBALS]\n",
            "whole number from 1",
        ),
    ];
    for (src, fragment) in cases {
        let errs = errors(src);
        assert_eq!(errs.len(), 1, "{src}: {errs:?}");
        assert!(errs[0].2.contains(fragment), "{src}: {:?}", errs[0].2);
    }
}

#[test]
fn missing_required_keys_point_at_the_block() {
    one_error(
        "\n[OBJECT]\ncolor1 = 1\n[/OBJECT]\n",
        2,
        1,
        &["needs `type"],
    );
    one_error("[LIGHT]\ncolor = 1\n[/LIGHT]\n", 1, 1, &["needs `position"]);
    let errs = errors("[CSG]\n[OBJECT]\ntype = sphere\n[/OBJECT]\n[/CSG]\n");
    assert!(errs.iter().any(|e| e.2.contains("needs `op")), "{errs:?}");
    assert!(errs.iter().any(|e| e.2.contains("two or more")), "{errs:?}");
}

#[test]
fn keys_that_do_not_apply_to_the_shape_are_errors() {
    one_error(
        "[OBJECT]\ntype = plane\nradius = 2\n[/OBJECT]\n",
        3,
        1,
        &["`radius` does not apply to a plane"],
    );
    one_error(
        "[OBJECT]\ntype = sphere\nmajor = 2\n[/OBJECT]\n",
        3,
        1,
        &["`major` does not apply to a sphere"],
    );
}

#[test]
fn conflicting_keys_are_errors() {
    one_error(
        "[OBJECT]\ntype = sphere\ncolor2 = 1\ntexture = a.png\n[/OBJECT]\n",
        3,
        1,
        &["color2", "texture"],
    );
    one_error(
        "[GLOBALS]\nantialias = on\nsampler = grid\n[/GLOBALS]\n",
        2,
        1,
        &["keep one"],
    );
    one_error(
        "[GLOBALS]\nsamples = 4\n[/GLOBALS]\n",
        2,
        1,
        &["`samples` applies to"],
    );
    one_error(
        "[GLOBALS]\nsampler = jitter\nthreshold = 0.1\n[/GLOBALS]\n",
        3,
        1,
        &["adaptive only"],
    );
}

/// A misspelt tag is one mistake: one error, not a cascade (the opener's block swallowing
/// the next, correct block and asking for its own misspelt closer). Each case is the one
/// typo's error alone, and the scene without the typo parses.
#[test]
fn a_misspelt_tag_is_one_error() {
    let sphere = "type = sphere\nradius = 3\n";
    let cube = "[OBJECT]\ntype = cube\n[/OBJECT]\n";
    ok(&format!("[OBJECT]\n{sphere}[/OBJECT]\n{cube}"));
    // The opener misspelt; its block ends at the known closer, which is not reported.
    one_error(
        &format!("[OBJCET]\n{sphere}[/OBJECT]\n{cube}"),
        1,
        1,
        &["unknown tag [OBJCET]", "did you mean [OBJECT]"],
    );
    // The closer misspelt: it closes the block it misspells.
    one_error(
        &format!("[OBJECT]\n{sphere}[/OBJCET]\n{cube}"),
        4,
        1,
        &["unknown tag [/OBJCET]", "did you mean [/OBJECT]"],
    );
    // An unknown block closed by its own name, and one whose closer never comes: the next
    // known tag ends it.
    one_error(
        &format!("[MATERIAL]\ncolor = <1,0,0>\n[/MATERIAL]\n{cube}"),
        1,
        1,
        &["unknown tag [MATERIAL]"],
    );
    one_error(
        &format!("[MATERIAL]\ncolor = <1,0,0>\n{cube}"),
        1,
        1,
        &["unknown tag [MATERIAL]"],
    );
    // An unknown wrapper around known blocks: its closer, after them, is not reported again.
    one_error(
        &format!("[OBJECTS]\n{cube}{cube}[/OBJECTS]\n"),
        1,
        1,
        &["unknown tag [OBJECTS]"],
    );
    // An unknown tag inside a known block: the block's own checks (a missing `type`) stay
    // quiet, since the unknown block may have swallowed the key.
    one_error(
        "[OBJECT]\n[MATERIAL]\ntype = sphere\n[/OBJECT]\n",
        2,
        1,
        &["unknown tag [MATERIAL]"],
    );
    // A misspelt container: its children are read as top-level blocks, and its real
    // closer (`[/CSG]`, `[/RAYFILE]`) is not reported again as closing nothing.
    let obj = "[OBJECT]\ntype = sphere\n[/OBJECT]\n";
    one_error(
        &format!("[CSGG]\nop = union\n{obj}{obj}[/CSG]\n"),
        1,
        1,
        &["unknown tag [CSGG]", "did you mean [CSG]"],
    );
    one_error(
        &format!("[RAYFLE]\n{cube}[/RAYFILE]\n"),
        1,
        1,
        &["unknown tag [RAYFLE]"],
    );
    // The same misspelling twice, once opening and once closing a real block: two errors,
    // each at its typo (not the second silently skipped and the next block blamed).
    let errs = errors(&format!(
        "[OBJCET]\n{sphere}[/OBJECT]\n[OBJECT]\ntype = cube\n[/OBJCET]\n{cube}"
    ));
    let at: Vec<(u32, u32)> = errs.iter().map(|e| (e.0, e.1)).collect();
    assert_eq!(at, vec![(1, 1), (7, 1)], "{errs:?}");
    assert!(errs[1].2.contains("unknown tag [/OBJCET]"), "{errs:?}");
    // A misspelling silences one closer, not every later one: a stray [/OBJECT] after the
    // misspelt block is closed by its own closer, or after its hint is used once, is still
    // reported.
    for src in [
        format!("[OBJCET]\n{sphere}[/OBJCET]\n{cube}[/OBJECT]\n"),
        format!("[CSGG]\nop = union\n{obj}{obj}[/CSG]\n[/CSG]\n"),
    ] {
        let errs = errors(&src);
        assert_eq!(errs.len(), 2, "{src}: {errs:?}");
        assert!(errs[1].2.contains("closes nothing"), "{errs:?}");
    }
    // A closer nobody opened and that misspells nothing still says so.
    one_error(&format!("{cube}[/OBJECT]\n"), 4, 1, &["closes nothing"]);
}

#[test]
fn tag_structure_errors() {
    one_error(
        "[OBJECT]\ntype = sphere\n",
        1,
        1,
        &["not closed", "end of the file"],
    );
    one_error("[/OBJECT]\n", 1, 1, &["closes nothing"]);
    one_error(
        "[LIGHT]\nposition = <0,0,0>\n[OBJECT]\ntype = sphere\n[/OBJECT]\n[/LIGHT]\n",
        3,
        1,
        &["cannot appear inside [LIGHT]"],
    );
    // `[GLOBAL]` and `[GLOBALS]` are one block, whichever spelling closes it (a mismatch
    // must not read "[/GLOBAL] closes nothing" while the block it would close is open).
    for (open, close) in [("GLOBALS", "GLOBAL"), ("GLOBAL", "GLOBALS")] {
        let d = ok(&format!("[{open}]\nwidth = 8\nheight = 6\n[/{close}]\n"));
        assert_eq!((d.width, d.height), (8, 6));
    }
    let errs = errors("[GLOBALS]\n[/GLOBALS]\n[GLOBAL]\n[/GLOBAL]\n");
    assert_eq!(errs.len(), 1);
    assert!(errs[0].2.contains("second globals"), "{errs:?}");
    let errs = errors("[CAMERA]\n[/CAMERA]\n[CAMERA]\n[/CAMERA]\n");
    assert!(errs[0].2.contains("second [CAMERA]"), "{errs:?}");
    one_error(
        "[GLOBALS]\n[/GLOBALS]\n[rayfile]\n[/rayfile]\n",
        3,
        1,
        &["[rayfile] may only wrap"],
    );
    // A close tag for an outer block reports the inner block left open.
    one_error(
        "[CSG]\nop = union\n[OBJECT]\ntype = sphere\n[/CSG]\n",
        3,
        1,
        &["[OBJECT] is not closed", "before line 5"],
    );
}

#[test]
fn lines_that_are_neither_tag_nor_entry() {
    one_error(
        "[OBJECT]\ntype sphere\n[/OBJECT]\n",
        2,
        1,
        &["expected `key = value`"],
    );
    one_error("[OBJECT]\n= sphere\n[/OBJECT]\n", 2, 1, &["expected a key"]);
    one_error("[OB JECT]\n", 1, 1, &["is not a tag"]);
}

#[test]
fn degenerate_cameras_and_transforms_are_errors() {
    one_error(
        "[CAMERA]\neye = <1, 2, 3>\nlook_at = <1, 2, 3>\n[/CAMERA]\n",
        1,
        1,
        &["same point"],
    );
    // Apart by 1e-300: the squared distance underflows (it said "the same point").
    one_error(
        "[CAMERA]\neye = <0, 0, 1e-300>\nlook_at = <0, 0, 0>\n[/CAMERA]\n",
        1,
        1,
        &["too close together", "1e-300 apart"],
    );
    one_error(
        "[CAMERA]\neye = <0, 10, 0>\nlook_at = <0, 0, 0>\nup = <0, 2, 0>\n[/CAMERA]\n",
        4,
        6,
        &["parallel"],
    );
    // 1e15 (the largest number) to the 20th is 1e300, to the 21st past the largest f64:
    // refused at the 21st step, line 23.
    one_error(
        &format!(
            "[OBJECT]\ntype = sphere\n{}[/OBJECT]\n",
            "scale = 1e15\n".repeat(21)
        ),
        23,
        1,
        &["singular or non-finite"],
    );
}

/// Numbers are at most 1e15 in magnitude, wherever they are written; past that, the error
/// is at the number. Each of these, accepted, would break something: a light at 1e154
/// lights nothing (its distance squared overflows), colours of 1e308 make NaN pixels that
/// come out white, an eye at 1e160 is said to look along `up`.
#[test]
fn numbers_past_the_largest_are_refused_where_they_are_written() {
    let limit = tessera_tracer::MAX_NUMBER;
    assert_eq!(limit, 1e15);
    ok("[LIGHT]\nposition = <1e15, -1e15, 1e15>\n[/LIGHT]\n");
    let cases = [
        (
            "[LIGHT]\nposition = <1e154, 1e154, 1e154>\n[/LIGHT]\n",
            2,
            13,
        ),
        ("[GLOBALS]\nambient = 1e308\n[/GLOBALS]\n", 2, 11),
        ("[CAMERA]\neye = <0, 0, 1e160>\n[/CAMERA]\n", 2, 14),
        (
            "[OBJECT]\ntype = sphere\nradius = 1.5e15\n[/OBJECT]\n",
            3,
            10,
        ),
        ("[OBJECT]\ntype = sphere\nscale = -2e15\n[/OBJECT]\n", 3, 9),
        (
            "[OBJECT]\ntype = sphere\ncolor1 = <1, 0, 1e16>\n[/OBJECT]\n",
            3,
            17,
        ),
    ];
    for (src, line, column) in cases {
        one_error(src, line, column, &["magnitude at most 1e15"]);
    }
    // A literal past the largest `f64` is too large too, not "not a number".
    one_error(
        "[OBJECT]\ntype = sphere\nradius = 1e400\n[/OBJECT]\n",
        3,
        10,
        &["magnitude at most 1e15"],
    );
    one_error(
        "[OBJECT]\ntype = sphere\nradius = -1e400\n[/OBJECT]\n",
        3,
        10,
        &["magnitude at most 1e15"],
    );
}

#[test]
fn several_independent_errors_are_reported_together_in_order() {
    let src = "\
[GLOBALS]
width = -3
hieght = 4
[/GLOBALS]
[OBJECT]
type = sphere
radius = big
[/OBJECT]
[LIGHT]
[/LIGHT]
";
    let errs = errors(src);
    let at: Vec<(u32, u32)> = errs.iter().map(|e| (e.0, e.1)).collect();
    assert_eq!(at, vec![(2, 9), (3, 1), (7, 10), (9, 1)], "{errs:?}");
}

#[test]
fn errors_format_as_file_line_col_message() {
    let err: SceneError =
        parse("[OBJECT]\ntype = cubee\n[/OBJECT]\n", &Limits::default()).expect_err("a bad type");
    let text = err.with_file("scene.ray").to_string();
    assert!(text.starts_with("scene.ray:2:8: "), "{text}");
}

/// Past the object limit the file is not read further (one error, at the first object too
/// many), so what the parser holds is bounded by the limit, not by the file (millions of
/// spheres would otherwise take gigabytes to be refused). Likewise past the most lines one
/// block may hold.
#[test]
fn the_reading_stops_at_the_object_and_block_limits() {
    let limits = Limits {
        max_objects: 3,
        ..Limits::default()
    };
    let sphere = "[OBJECT]\ntype = sphere\n[/OBJECT]\n";
    // Three objects are fine; the fourth [OBJECT] (line 10) is the error, and the bad line
    // after it is not read.
    parse(&sphere.repeat(3), &limits).expect("three objects");
    let src = format!("{}width = x\n", sphere.repeat(10));
    let errs = errors_with(&src, &limits);
    assert_eq!(errs.len(), 1, "{errs:?}");
    assert_eq!((errs[0].0, errs[0].1), (10, 1));
    assert!(
        errs[0].2.contains("too many objects: the limit is 3"),
        "{errs:?}"
    );
    // CSG children count: two children and a loose sphere are three, a fourth is refused.
    let csg = format!("[CSG]\nop = union\n{sphere}{sphere}[/CSG]\n");
    parse(&format!("{csg}{sphere}"), &limits).expect("three objects");
    let errs = errors_with(&format!("{csg}{sphere}{sphere}"), &limits);
    assert_eq!(errs.len(), 1, "{errs:?}");
    assert_eq!(errs[0].0, 13);

    // Blocks of any kind count: 30 lights where 2 are allowed stop at the 25th block (twice
    // the objects, the lights and 16), not at the end of the file.
    let limits = Limits {
        max_objects: 3,
        max_lights: 2,
        ..Limits::default()
    };
    let light = "[LIGHT]\nposition = <0, 1, 0>\n[/LIGHT]\n";
    let errs = errors_with(&light.repeat(30), &limits);
    let stop = errs
        .iter()
        .find(|e| e.2.contains("more than 24 blocks"))
        .unwrap_or_else(|| panic!("{errs:?}"));
    assert_eq!((stop.0, stop.1), (73, 1));
    assert!(errs.iter().all(|e| e.0 <= 73), "{errs:?}");

    let max = tessera_tracer::MAX_BLOCK_ENTRIES;
    // A `[rayfile]` inside a block adds its lines to the block's all at once: the next line
    // is past the cap all the same.
    let src = format!(
        "[OBJECT]\ntype = sphere\n{}[RAYFILE]\n{}[/RAYFILE]\nscale = 1\n[/OBJECT]\n",
        "scale = 1\n".repeat(max - 10),
        "scale = 1\n".repeat(20)
    );
    let errs = errors(&src);
    assert!(
        errs.iter().any(|e| e.0 as usize == max + 15
            && e.2.contains(&format!("more than {max} lines in [OBJECT]"))),
        "{errs:?}"
    );
    let chain = |n: usize| {
        format!(
            "[OBJECT]\ntype = sphere\n{}[/OBJECT]\n",
            "scale = 1\n".repeat(n - 1)
        )
    };
    ok(&chain(max));
    let errs = errors(&format!("{}width = x\n", chain(max + 1)));
    assert_eq!(errs.len(), 1, "{errs:?}");
    assert_eq!((errs[0].0, errs[0].1), ((max + 2) as u32, 1));
    assert!(
        errs[0]
            .2
            .contains(&format!("more than {max} lines in [OBJECT]")),
        "{errs:?}"
    );
}

#[test]
fn limits_are_enforced() {
    let limits = Limits {
        max_dimension: 100,
        max_pixels: 5_000,
        max_objects: 2,
        max_csg_depth: 1,
        max_lights: 1,
        max_textures: 1,
        max_bounces: 8,
        max_samples: 4,
    };
    let check = |src: &str, fragment: &str| {
        let errs = errors_with(src, &limits);
        assert!(
            errs.iter().any(|e| e.2.contains(fragment)),
            "{src}: {errs:?} lacks {fragment}"
        );
    };
    check("[GLOBALS]\nwidth = 101\n[/GLOBALS]\n", "from 1 to 100");
    // A size refused is the one error about the size: the defaults standing in for it
    // (640×480, over both limits here) are not reported as well, and first.
    for src in [
        "[GLOBALS]\nwidth = 101\nheight = 4\n[/GLOBALS]\n",
        "[GLOBALS]\nwidth = 480\nheight = 360\n[/GLOBALS]\n",
    ] {
        let errs = errors_with(src, &limits);
        assert!(
            !errs.is_empty() && errs.iter().all(|e| e.2.contains("from 1 to 100")),
            "{src}: {errs:?}"
        );
    }
    // A default that is over the limits is named as the default, with what to set.
    for (src, says) in [
        (
            "[GLOBALS]\nwidth = 50\n[/GLOBALS]\n",
            "the default height in 50×480",
        ),
        (
            "[GLOBALS]\nheight = 50\n[/GLOBALS]\n",
            "the default width in 640×50",
        ),
        (
            "[GLOBALS]\nambient = 0.1\n[/GLOBALS]\n",
            "the default image size 640×480",
        ),
        ("[CAMERA]\n[/CAMERA]\n", "the default image size 640×480"),
    ] {
        let errs = errors_with(src, &limits);
        assert!(errs.iter().any(|e| e.2.contains(says)), "{src}: {errs:?}");
    }
    check(
        "[GLOBALS]\nwidth = 100\nheight = 51\n[/GLOBALS]\n",
        "the limit is 5000",
    );
    let sphere = "[OBJECT]\ntype = sphere\n[/OBJECT]\n";
    check(&sphere.repeat(3), "too many objects");
    check(
        "[LIGHT]\nposition = <0,0,0>\n[/LIGHT]\n[LIGHT]\nposition = <0,0,0>\n[/LIGHT]\n",
        "2 lights",
    );
    // The error is at the light past the limit, a block or the global key alike.
    for (src, at) in [
        (
            "[LIGHT]\nposition = <0,0,0>\n[/LIGHT]\n[LIGHT]\nposition = <0,0,0>\n[/LIGHT]\n",
            (4, 1),
        ),
        (
            "[LIGHT]\nposition = <0,0,0>\n[/LIGHT]\n[GLOBALS]\nlight = <1,1,1>\n[/GLOBALS]\n",
            (5, 1),
        ),
    ] {
        let errs = errors_with(src, &limits);
        assert!(
            errs.iter()
                .any(|e| (e.0, e.1) == at && e.2.contains("2 lights")),
            "{errs:?}"
        );
    }
    // A radius that makes the sphere's matrix singular is the radius's fault.
    let errs = errors("[OBJECT]\ntype = sphere\nradius = 1e-320\n[/OBJECT]\n");
    assert!(
        errs.iter()
            .any(|e| (e.0, e.1) == (3, 1) && e.2.contains("singular")),
        "{errs:?}"
    );
    check(
        "[OBJECT]\ntype = plane\ntexture = a.png\n[/OBJECT]\n\
         [OBJECT]\ntype = plane\ntexture = b.png\n[/OBJECT]\n",
        "too many texture",
    );
    check("[GLOBALS]\nmax_depth = 9\n[/GLOBALS]\n", "from 0 to 8");
    check(
        "[GLOBALS]\nsampler = grid\nsamples = 5\n[/GLOBALS]\n",
        "from 1 to 4",
    );
    let nested = "[CSG]\nop = union\n[CSG]\nop = union\n[OBJECT]\ntype = sphere\n[/OBJECT]\n\
                  [OBJECT]\ntype = sphere\n[/OBJECT]\n[/CSG]\n[OBJECT]\ntype = sphere\n[/OBJECT]\n[/CSG]\n";
    check(nested, "nested too deeply");
}

#[test]
fn csg_blocks_parse_with_their_children_and_transforms() {
    let d = ok("\
[CSG]
op = difference
translate = <0, 1, 0>
[OBJECT]
type = sphere
[/OBJECT]
[CSG]
op = intersection
[OBJECT]
type = sphere
[/OBJECT]
[OBJECT]
type = plane
[/OBJECT]
[/CSG]
[/CSG]
");
    let Node::Csg(c) = &d.objects[0] else {
        panic!("a CSG")
    };
    assert_eq!(c.op, CsgOp::Difference);
    assert_eq!(c.children.len(), 2);
    assert!(matches!(&c.children[1], Node::Csg(inner) if inner.op == CsgOp::Intersection));
    assert_eq!(d.primitive_count(), 3);
    one_error(
        "[CSG]\nop = union\ncolor1 = 1\n[OBJECT]\ntype = sphere\n[/OBJECT]\n[OBJECT]\ntype = sphere\n[/OBJECT]\n[/CSG]\n",
        3,
        1,
        &["material of its [OBJECT] children"],
    );
}

#[test]
fn hostile_input_is_refused_quickly_and_without_panic() {
    // Long lines, odd bytes and deep nesting: errors, not crashes.
    let long_key = format!("[GLOBALS]\n{} = 1\n[/GLOBALS]\n", "w".repeat(100_000));
    assert!(parse(&long_key, &Limits::default()).is_err());
    let opens = "[CSG]\n".repeat(10_000);
    assert!(parse(&opens, &Limits::default()).is_err());
    let junk = "\u{0}\u{feff}[\u{1F600}]\n=\n[/]\n<<<>>>\n";
    assert!(parse(junk, &Limits::default()).is_err());
}

/// `[CSG]` nested `depth` deep inside `[rayfile]`: each level a union of a sphere and the next
/// level, the deepest a union of two spheres.
fn nested_csg(depth: usize) -> String {
    let sphere = "[OBJECT]\ntype = sphere\n[/OBJECT]\n";
    let mut s = String::from("[rayfile]\n");
    for _ in 0..depth {
        s.push_str("[CSG]\nop = union\n");
        s.push_str(sphere);
    }
    s.push_str(sphere);
    s.push_str(&"[/CSG]\n".repeat(depth));
    s.push_str("[/rayfile]\n");
    s
}

/// The deepest nesting the limit allows parses, inside `[rayfile]` and with an `[OBJECT]` at
/// the bottom; one level more is refused at that level.
#[test]
fn csg_nests_to_its_limit_and_no_further() {
    let limit = Limits::default().max_csg_depth;
    let d = ok(&nested_csg(limit));
    fn depth(n: &Node) -> usize {
        match n {
            Node::Object(_) => 0,
            Node::Csg(c) => 1 + c.children.iter().map(depth).max().unwrap_or(0),
        }
    }
    assert_eq!(d.objects.len(), 1);
    assert_eq!(depth(&d.objects[0]), limit);
    let errs = errors(&nested_csg(limit + 1));
    // The level past the limit opens on the line after the `[rayfile]` line and the limit's
    // levels, five lines each; that is the one error.
    let line = 2 + 5 * limit as u32;
    assert_eq!(
        errs,
        [(
            line,
            1,
            format!("[CSG] nested too deeply: the limit is {limit} levels")
        )]
    );
}

/// Tags nested far past the limit are refused a few levels past what any valid scene
/// needs, and the reading stops there: parsing 100,000 open `[CSG]` tags (600 KB) takes a
/// bounded stack. Without the stop the tree would be as deep as the file and dropping it
/// alone would overflow the main thread's 8 MB stack; here the parse runs on a thread of
/// 256 KB.
#[test]
fn runaway_nesting_is_refused_on_a_small_stack() {
    let limit = Limits::default().max_csg_depth;
    let src = "[CSG]\n".repeat(100_000);
    let errs = std::thread::Builder::new()
        .stack_size(256 * 1024)
        .spawn(move || errors(&src))
        .expect("thread starts")
        .join()
        .expect("the parse returns");
    // The CSG check's limit plus room for `[rayfile]`, an `[OBJECT]` and a few levels too
    // many (72 blocks, one a line); the next tag is refused and nothing after it is read.
    let stop = (limit + 9) as u32;
    assert!(
        errs.iter()
            .any(|e| (e.0, e.1) == (stop, 1) && e.2.contains("the rest of the file is not read")),
        "{errs:?}"
    );
    assert!(errs.iter().all(|e| e.0 <= stop), "{errs:?}");
}

/// A UTF-8 byte-order mark before the first tag is not an error (nor four), and the first
/// line's columns count from after it.
#[test]
fn a_byte_order_mark_is_skipped() {
    let plain = "[GLOBALS]\nwidth = 8\nheight = 4\n[/GLOBALS]\n";
    let d = ok(&format!("\u{feff}{plain}"));
    assert_eq!(d, ok(plain));
    one_error(
        "\u{feff}[GLOBALS]\nwidth = x\n[/GLOBALS]\n",
        2,
        9,
        &["`width`"],
    );
    one_error("\u{feff}width = 8\n", 1, 1, &["outside every block"]);
}

/// Control characters quoted from the scene come out escaped: a message is one line of
/// plain text, whatever the file held (a NUL, a terminal escape sequence, a carriage return).
#[test]
fn quoted_control_characters_are_escaped() {
    let errs = errors("[GLOBALS]\nwidth = 8\u{0}\u{1b}[31m\r\n[/GLOBALS]\n");
    assert_eq!(errs.len(), 1, "{errs:?}");
    let (line, column, message) = &errs[0];
    assert_eq!((*line, *column), (2, 9));
    assert!(!message.contains(char::is_control), "{message:?}");
    assert!(message.contains("`8\\0\\u{1b}[31m`"), "{message}");
}

/// Characters that print as nothing (a zero-width space pasted from a web page, a
/// byte-order mark in mid-file) are shown escaped where a message quotes them: the message
/// read "found `` in `width`".
#[test]
fn quoted_invisible_characters_are_escaped() {
    for (c, escaped) in [
        ('\u{200b}', "\\u{200b}"),
        ('\u{feff}', "\\u{feff}"),
        ('\u{202e}', "\\u{202e}"),
        ('\u{2060}', "\\u{2060}"),
    ] {
        let errs = errors(&format!("[GLOBALS]\n{c}width = 8\n[/GLOBALS]\n"));
        assert_eq!(errs.len(), 1, "{errs:?}");
        let message = &errs[0].2;
        assert!(!message.contains(c), "{message:?}");
        assert!(
            message.contains(&format!("found `{escaped}` in `{escaped}width`")),
            "{message}"
        );
    }
}

/// Names quoted in messages are cut short, as values are: a line of a binary file read as a
/// key, or a tag of 50,000 letters, is not echoed whole (a 1 MB key would make a 1 MB
/// message).
#[test]
fn quoted_names_are_cut_short() {
    let long = "x".repeat(50_000);
    let cases = [
        format!("[GLOBALS]\n{long} = 1\n[/GLOBALS]\n"),
        format!("[GLOBALS]\n[/GLOBALS]\n{long} = 1\n"),
        format!("[{long}]\n[/{long}]\n"),
        format!("[OBJECT]\ntype = sphere\n[/{long}]\n"),
        format!("[GLOBALS]\n{long}! = 1\n[/GLOBALS]\n"),
        format!("[{long}!]\n"),
    ];
    for src in &cases {
        let errs = errors(src);
        for (_, _, message) in &errs {
            assert!(
                message.len() < 300,
                "{} bytes: {}",
                message.len(),
                &message[..300]
            );
        }
        assert!(
            errs.iter()
                .any(|(_, _, m)| m.to_ascii_lowercase().contains("xxx...")),
            "{errs:?}"
        );
    }
}

/// A line far longer than any scene line is refused on its own, at its line, and the lines
/// around it are still read: a 100 MB line is not widened to 400 MB of characters before
/// its first is refused.
#[test]
fn an_overlong_line_is_one_error() {
    let long = format!("color = <{}>", "1,".repeat(40_000));
    let errs = errors(&format!(
        "[GLOBALS]\nwidth = 8\n{long}\nheight = x\n[/GLOBALS]\n"
    ));
    assert_eq!(errs.len(), 2, "{errs:?}");
    assert_eq!((errs[0].0, errs[0].1), (3, 1));
    assert!(errs[0].2.contains("80010 bytes"), "{}", errs[0].2);
    assert_eq!((errs[1].0, errs[1].1), (4, 10));
    // Just under the cap, a line is read as usual (its value is then wrong, and says so).
    let under = format!("ambient = {}", "1".repeat(65_536 - 10));
    let errs = errors(&format!("[GLOBALS]\n{under}\n[/GLOBALS]\n"));
    assert_eq!(errs.len(), 1, "{errs:?}");
    assert!(!errs[0].2.contains("bytes"), "{}", errs[0].2);
}

/// A file of many bad lines reports the first hundred and says how many more there were,
/// at the first of them.
#[test]
fn errors_are_capped_with_a_count_of_the_rest() {
    let max = tessera_tracer::MAX_DIAGNOSTICS;
    // One unknown key a line, each a different one: one error a line.
    let keys: String = (0..max + 25).map(|i| format!("k{i} = 1\n")).collect();
    let errs = errors(&format!("[GLOBALS]\n{keys}[/GLOBALS]\n"));
    assert_eq!(errs.len(), max + 1);
    // Line 2 holds the first; the note is at the first not shown.
    assert_eq!((errs[0].0, errs[0].1), (2, 1));
    let last = &errs[max];
    assert_eq!((last.0, last.1), ((max + 2) as u32, 1));
    assert_eq!(last.2, "25 more errors from here on are not shown");
}

/// The count past the first hundred is exact however many there are, and which are shown
/// does not depend on the order the checks found them in: errors found late (a missing
/// `type`, found after every line is read) but written early are among those shown. The
/// parser keeps only a few hundred at a time (the memory of a million bad lines), so this
/// checks its bounded list against the same errors counted line by line.
#[test]
fn many_errors_are_counted_exactly_and_the_earliest_shown() {
    let max = tessera_tracer::MAX_DIAGNOSTICS;
    let bad = 5_000;
    // Line 1 opens an object with no `type` (reported after all lines are read, at line 1);
    // then one malformed line each (found by the lexer first).
    let lines: String = (0..bad).map(|i| format!("junk {i}\n")).collect();
    let errs = errors(&format!("[OBJECT]\nradius = 2\n[/OBJECT]\n{lines}"));
    assert_eq!(errs.len(), max + 1);
    // Missing `type` at 1:1, then the junk lines from line 4 on.
    assert_eq!((errs[0].0, errs[0].1), (1, 1), "{:?}", errs[0]);
    assert!(errs[0].2.contains("type"), "{:?}", errs[0]);
    for (k, e) in errs[1..max].iter().enumerate() {
        assert_eq!(e.0, 4 + k as u32, "{e:?}");
    }
    let total = bad + 1;
    assert_eq!(
        errs[max].2,
        format!("{} more errors from here on are not shown", total - max)
    );
    assert_eq!(errs[max].0, 4 + (max - 1) as u32);
}

/// `[rayfile]` wraps the whole scene: anything after its close is an error, once, at the
/// first thing after it (it is not read as part of the scene).
#[test]
fn nothing_follows_the_rayfile_wrapper() {
    let inside = "[rayfile]\n[GLOBALS]\nwidth = 8\n[/GLOBALS]\n[/rayfile]\n";
    ok(inside);
    ok(&format!("# a comment\n{inside}\n# another\n"));
    let after = format!("{inside}[OBJECT]\ntype = sphere\n[/OBJECT]\n[LIGHT]\n[/LIGHT]\n");
    let errs = errors(&after);
    let reported: Vec<_> = errs
        .iter()
        .filter(|e| e.2.contains("after [/rayfile] (line 5)"))
        .map(|e| (e.0, e.1))
        .collect();
    assert_eq!(reported, [(6, 1)], "{errs:?}");
}
