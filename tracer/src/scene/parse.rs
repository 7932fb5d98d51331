//! The `.ray` parser: items from the lexer → a block tree → a validated [`SceneDesc`].
//!
//! Errors are collected, not thrown: a bad value, an unknown key or a misplaced tag is
//! recorded and parsing goes on with the next item, so one run reports every independent
//! mistake. Only the final result is all-or-nothing.

use std::collections::HashMap;

use glam::DVec3;

use super::lex::Lexer;
use super::{
    CameraDesc, CsgDesc, CsgOp, Light, Limits, MaterialDesc, Node, ObjectDesc, SceneDesc,
    TextureRef,
};
use crate::diag::{Diagnostic, Found, Pos, SceneError, closest, shorten};
use crate::math::Color;
use crate::sampler::Sampler;
use crate::shape::Shape;
use crate::transform::{Transform, TransformOp};

use super::blocks::{Block, Caps, Entry, build_tree};
use super::value::{GivenSize, Value};

pub(super) const GLOBAL_KEYS: &[&str] = &[
    "width",
    "height",
    "ambient",
    "shadow",
    "background",
    "max_depth",
    "antialias",
    "sampler",
    "samples",
    "threshold",
    "light",
];
pub(super) const CAMERA_KEYS: &[&str] = &["eye", "look_at", "up", "fov"];
pub(super) const LIGHT_KEYS: &[&str] = &["position", "color"];
pub(super) const TRANSFORM_KEYS: &[&str] = &["scale", "rotate", "translate"];
pub(super) const MATERIAL_KEYS: &[&str] = &[
    "color1",
    "color2",
    "texture",
    "mirror",
    "reflection",
    "diffuse",
];
pub(super) const OBJECT_KEYS: &[&str] = &[
    "type",
    "radius",
    "major",
    "minor",
    "color1",
    "color2",
    "texture",
    "mirror",
    "reflection",
    "diffuse",
    "scale",
    "rotate",
    "translate",
];
pub(super) const CSG_KEYS: &[&str] = &["op", "scale", "rotate", "translate"];
pub(super) const SHAPES: &[&str] = &["sphere", "plane", "cube", "cylinder", "cone", "torus"];
pub(super) const SAMPLERS: &[&str] = &["center", "thesis", "grid", "jitter", "adaptive"];

/// Parses and validates a `.ray` scene. All problems found are returned together, sorted by
/// position.
pub fn parse(source: &str, limits: &Limits) -> Result<SceneDesc, SceneError> {
    // A byte-order mark (Windows editors write one) is not part of the text: columns on the
    // first line count from after it, as an editor shows them.
    let source = source.strip_prefix('\u{feff}').unwrap_or(source);
    let mut errors = Found::default();
    let root = build_tree(Lexer::new(source), &mut errors, Caps::of(limits));
    let mut p = Parser {
        errors,
        limits,
        textures: Vec::new(),
        light_pos: Vec::new(),
    };
    let desc = p.scene(root);
    match p.errors.into_error() {
        None => Ok(desc),
        Some(e) => Err(e),
    }
}

pub(super) struct Parser<'a> {
    errors: Found,
    limits: &'a Limits,
    textures: Vec<String>,
    /// Where each light of the scene was written, in the order they are counted.
    light_pos: Vec<Pos>,
}

/// Which block kinds a key belongs to, for "`fov` belongs in [CAMERA]" hints.
pub(super) fn home_of(key: &str) -> Option<&'static str> {
    if GLOBAL_KEYS.contains(&key) {
        Some("[GLOBALS]")
    } else if CAMERA_KEYS.contains(&key) {
        Some("[CAMERA]")
    } else if LIGHT_KEYS.contains(&key) {
        Some("[LIGHT]")
    } else if OBJECT_KEYS.contains(&key) {
        Some("[OBJECT]")
    } else if CSG_KEYS.contains(&key) {
        Some("[CSG]")
    } else {
        None
    }
}

impl Parser<'_> {
    fn err(&mut self, pos: Pos, message: impl Into<String>) {
        self.errors.push(Diagnostic::new(pos, message));
    }

    /// The scene of the block tree `root`, taken apart as it is read: each top-level block
    /// is dropped once its node is made, so that the tree and the nodes are not both held
    /// whole (for a scene of many small objects, each is the larger part of its memory).
    fn scene(&mut self, root: Block) -> SceneDesc {
        let mut desc = SceneDesc {
            width: 640,
            height: 480,
            ambient: Color::splat(0.1),
            shadow: 1.0,
            background: Color::ZERO,
            max_depth: 5,
            sampler: Sampler::Center,
            camera: CameraDesc::default(),
            lights: Vec::new(),
            // Sized once: growing by doubling would hold up to twice the nodes at its peak.
            objects: Vec::with_capacity(
                root.children
                    .iter()
                    .filter(|b| matches!(b.name.as_str(), "object" | "csg"))
                    .count(),
            ),
        };
        for e in &root.entries {
            let hint = match home_of(&e.key) {
                Some(home) => format!("; it belongs inside {home}"),
                None => String::new(),
            };
            self.err(
                e.key_pos,
                format!("`{}` is outside every block{hint}", shorten(&e.key)),
            );
        }
        let mut globals_at: Option<Pos> = None;
        let mut size = GivenSize::default();
        let mut camera_at: Option<Pos> = None;
        for b in root.children {
            let b = &b;
            match b.name.as_str() {
                "globals" | "global" => {
                    if let Some(first) = globals_at {
                        self.err(
                            b.pos,
                            format!(
                                "a second globals block; the first is at line {}",
                                first.line
                            ),
                        );
                    } else {
                        globals_at = Some(b.pos);
                        size = self.globals(b, &mut desc);
                    }
                }
                "camera" => {
                    if let Some(first) = camera_at {
                        self.err(
                            b.pos,
                            format!("a second [CAMERA]; the first is at line {}", first.line),
                        );
                    } else {
                        camera_at = Some(b.pos);
                        desc.camera = self.camera(b);
                    }
                }
                "light" => {
                    if let Some(l) = self.light(b) {
                        desc.lights.push(l);
                        self.light_pos.push(b.pos);
                    }
                }
                "object" | "csg" => {
                    if let Some(n) = self.node(b, 0) {
                        desc.objects.push(n);
                    }
                }
                _ => {} // unknown tags were reported while nesting
            }
        }
        if desc.lights.len() > self.limits.max_lights {
            // At the first light past the limit.
            let at = self
                .light_pos
                .get(self.limits.max_lights)
                .copied()
                .unwrap_or(Pos::new(1, 1));
            self.err(
                at,
                format!(
                    "the scene has {} lights; the limit is {}",
                    desc.lights.len(),
                    self.limits.max_lights
                ),
            );
        }
        // The defaults (640×480) count against the limits too, where no size was given. A
        // size given and refused has its own error, and the default standing in for it is
        // not the scene's fault (a message about "the default image size" would blame a size
        // the scene never asked for).
        let pixels = u64::from(desc.width) * u64::from(desc.height);
        let max_dim = self.limits.max_dimension;
        if !size.refused
            && ((!size.width && desc.width > max_dim)
                || (!size.height && desc.height > max_dim)
                || (globals_at.is_none() && pixels > self.limits.max_pixels))
        {
            let (what, set) = match (size.width, size.height) {
                (false, false) => ("the default image size", "`width` and `height`"),
                (false, true) => ("the default width in", "`width`"),
                _ => ("the default height in", "`height`"),
            };
            self.err(
                globals_at.unwrap_or(Pos::new(1, 1)),
                format!(
                    "{what} {}×{} is over this service's limits ({max_dim} a side, {} \
                     pixels): set {set} in [GLOBALS]",
                    desc.width, desc.height, self.limits.max_pixels
                ),
            );
        }
        desc
    }

    /// Checks keys against the block's list, reports unknown and duplicated ones, and returns
    /// the entries to interpret (transform keys may repeat; others may not).
    fn entries<'b>(&mut self, b: &'b Block, keys: &[&str]) -> Vec<&'b Entry> {
        // Each key's first entry: where, and the spelling used there (`mirror` or its alias).
        let mut seen: HashMap<&str, (Pos, &str)> = HashMap::new();
        let mut out = Vec::new();
        for e in &b.entries {
            if !keys.contains(&e.key.as_str()) {
                let msg = self.unknown_key_message(b, &e.key, keys);
                self.err(e.key_pos, msg);
                continue;
            }
            let canonical = if e.key == "reflection" {
                "mirror"
            } else {
                e.key.as_str()
            };
            if !TRANSFORM_KEYS.contains(&canonical) {
                if let Some((first, first_key)) = seen.get(canonical) {
                    let message = if *first_key == e.key {
                        format!(
                            "`{}` is given twice in {}; the first is at line {}",
                            e.key,
                            b.display(),
                            first.line
                        )
                    } else {
                        format!(
                            "`{}` repeats `{first_key}` (line {}): they are one key, given \
                             once in {}",
                            e.key,
                            first.line,
                            b.display()
                        )
                    };
                    self.err(e.key_pos, message);
                    continue;
                }
                seen.insert(canonical, (e.key_pos, e.key.as_str()));
            }
            out.push(e);
        }
        out
    }

    fn unknown_key_message(&self, b: &Block, key: &str, keys: &[&str]) -> String {
        let block = b.display();
        if b.name == "csg" && MATERIAL_KEYS.contains(&key) {
            return format!(
                "`{key}` is not a [CSG] key: a CSG surface takes the material of its [OBJECT] children"
            );
        }
        if let Some(s) = closest(key, keys.iter().copied()) {
            return format!("unknown key `{key}` in {block}; did you mean `{s}`?");
        }
        if let Some(home) = home_of(key) {
            return format!("`{key}` is not a {block} key; it belongs in {home}");
        }
        format!(
            "unknown key `{}` in {block}; expected one of: {}",
            shorten(key),
            keys.join(", ")
        )
    }

    fn globals(&mut self, b: &Block, desc: &mut SceneDesc) -> GivenSize {
        let mut size = GivenSize::default();
        let entries = self.entries(b, GLOBAL_KEYS);
        let mut antialias: Option<(bool, Pos)> = None;
        let mut sampler: Option<(&str, Pos)> = None;
        let mut samples: Option<(u32, Pos)> = None;
        let mut threshold: Option<(f64, Pos)> = None;
        let mut width_pos = b.pos;
        for e in entries {
            let v = Value::new(e);
            match e.key.as_str() {
                "width" | "height" => {
                    let max = self.limits.max_dimension;
                    if e.key == "width" {
                        size.width = true;
                    } else {
                        size.height = true;
                    }
                    match self.check(v.whole(1, max)) {
                        Some(n) if e.key == "width" => {
                            desc.width = n;
                            width_pos = e.value_pos;
                        }
                        Some(n) => desc.height = n,
                        None => size.refused = true,
                    }
                }
                "ambient" => {
                    if let Some(c) = self.check(v.color()) {
                        desc.ambient = c;
                    }
                }
                "background" => {
                    if let Some(c) = self.check(v.color()) {
                        desc.background = c;
                    }
                }
                "shadow" => {
                    if let Some(x) = self.check(v.number_in(0.0, 1.0)) {
                        desc.shadow = x;
                    }
                }
                "max_depth" => {
                    if let Some(n) = self.check(v.whole(0, self.limits.max_bounces)) {
                        desc.max_depth = n;
                    }
                }
                "antialias" => {
                    if let Some(f) = self.check(v.flag()) {
                        antialias = Some((f, e.key_pos));
                    }
                }
                "sampler" => {
                    if let Some(s) = self.check(v.keyword(SAMPLERS, "sampler")) {
                        sampler = Some((s, e.key_pos));
                    }
                }
                "samples" => {
                    if let Some(n) = self.check(v.whole(1, self.limits.max_samples)) {
                        samples = Some((n, e.key_pos));
                    }
                }
                "threshold" => {
                    if let Some(x) = self.check(v.positive()) {
                        threshold = Some((x, e.key_pos));
                    }
                }
                "light" => {
                    if let Some(p) = self.check(v.vector()) {
                        self.light_pos.push(e.key_pos);
                        desc.lights.push(Light {
                            position: p,
                            color: Color::ONE,
                        });
                    }
                }
                _ => {}
            }
        }
        if !size.refused && u64::from(desc.width) * u64::from(desc.height) > self.limits.max_pixels
        {
            self.err(
                width_pos,
                format!(
                    "the image is {}×{} = {} pixels; the limit is {}",
                    desc.width,
                    desc.height,
                    u64::from(desc.width) * u64::from(desc.height),
                    self.limits.max_pixels
                ),
            );
        }
        desc.sampler = self.sampler(antialias, sampler, samples, threshold);
        size
    }

    fn sampler(
        &mut self,
        antialias: Option<(bool, Pos)>,
        sampler: Option<(&str, Pos)>,
        samples: Option<(u32, Pos)>,
        threshold: Option<(f64, Pos)>,
    ) -> Sampler {
        if let (Some((_, at)), Some(_)) = (antialias, sampler) {
            self.err(
                at,
                "`antialias` and `sampler` both choose the sampling; keep one",
            );
        }
        let name = match (sampler, antialias) {
            (Some((s, _)), _) => s,
            (None, Some((true, _))) => "thesis",
            _ => "center",
        };
        let takes_samples = matches!(name, "grid" | "jitter" | "adaptive");
        if let (false, Some((_, at))) = (takes_samples, samples) {
            self.err(
                at,
                format!("`samples` applies to sampler = grid, jitter or adaptive, not {name}"),
            );
        }
        if let (true, Some((_, at))) = (name != "adaptive", threshold) {
            self.err(at, "`threshold` applies to sampler = adaptive only");
        }
        let n = samples.map(|(n, _)| n);
        match name {
            "thesis" => Sampler::Thesis,
            "grid" => Sampler::Grid { n: n.unwrap_or(4) },
            "jitter" => Sampler::Jitter { n: n.unwrap_or(4) },
            "adaptive" => Sampler::Adaptive {
                max: n.unwrap_or(Sampler::DEFAULT_ADAPTIVE_MAX),
                threshold: threshold.map_or(Sampler::DEFAULT_THRESHOLD, |(t, _)| t),
            },
            _ => Sampler::Center,
        }
    }

    fn camera(&mut self, b: &Block) -> CameraDesc {
        let mut cam = CameraDesc::default();
        let mut up_pos = b.pos;
        for e in self.entries(b, CAMERA_KEYS) {
            let v = Value::new(e);
            match e.key.as_str() {
                "eye" => {
                    if let Some(p) = self.check(v.vector()) {
                        cam.eye = p;
                    }
                }
                "look_at" => {
                    if let Some(p) = self.check(v.vector()) {
                        cam.look_at = p;
                    }
                }
                "up" => {
                    if let Some(p) = self.check(v.vector()) {
                        cam.up = p;
                        up_pos = e.value_pos;
                    }
                }
                "fov" => {
                    if let Some(f) = self.check(v.number_open(0.0, 180.0)) {
                        cam.fov_degrees = f;
                    }
                }
                _ => {}
            }
        }
        let forward = cam.look_at - cam.eye;
        if forward == DVec3::ZERO {
            self.err(b.pos, "the camera's `eye` and `look_at` are the same point");
        } else if !(forward.length_squared() > 0.0 && forward.is_finite()) {
            // Apart, but by less than about 1e-154: the squared distance underflows and no
            // direction can be computed.
            self.err(
                b.pos,
                format!(
                    "the camera's `eye` and `look_at` are too close together for a view \
                     direction ({:e} apart); place them farther apart",
                    forward.abs().max_element()
                ),
            );
        } else if cam.up.length_squared() == 0.0
            || forward.normalize().cross(cam.up.normalize()).length() < 1e-9
        {
            self.err(
                up_pos,
                "the camera's `up` is parallel to its view direction (or zero); choose another",
            );
        }
        cam
    }

    fn light(&mut self, b: &Block) -> Option<Light> {
        let mut position = None;
        let mut color = Color::ONE;
        for e in self.entries(b, LIGHT_KEYS) {
            let v = Value::new(e);
            match e.key.as_str() {
                "position" => position = self.check(v.vector()),
                "color" => {
                    if let Some(c) = self.check(v.color()) {
                        color = c;
                    }
                }
                _ => {}
            }
        }
        if position.is_none() && !b.broken && !b.entries.iter().any(|e| e.key == "position") {
            self.err(b.pos, "[LIGHT] needs `position = <x, y, z>`");
        }
        Some(Light {
            position: position?,
            color,
        })
    }

    fn node(&mut self, b: &Block, depth: usize) -> Option<Node> {
        match b.name.as_str() {
            "object" => self.object(b).map(Node::Object),
            "csg" => self.csg(b, depth + 1).map(Node::Csg),
            _ => None,
        }
    }

    fn object(&mut self, b: &Block) -> Option<ObjectDesc> {
        let entries = self.entries(b, OBJECT_KEYS);
        let errors_before = self.errors.pushed();

        // The shape first: which own keys apply depends on it.
        let kind = match entries.iter().find(|e| e.key == "type") {
            None if b.broken => None,
            None => {
                self.err(
                    b.pos,
                    format!("[OBJECT] needs `type = {}`", SHAPES.join("|")),
                );
                None
            }
            Some(e) => self.check(Value::new(e).keyword(SHAPES, "type")),
        };

        let mut radius: Option<f64> = None;
        let mut major: Option<f64> = None;
        let mut minor: Option<f64> = None;
        let mut material = MaterialDesc::default();
        let mut steps: Vec<(TransformOp, Pos)> = Vec::new();
        let mut color2_pos = None;
        for e in &entries {
            let v = Value::new(e);
            let own = |shapes: &[&str]| kind.is_none_or(|k| shapes.contains(&k));
            match e.key.as_str() {
                "radius" | "major" | "minor" => {
                    let applies = match e.key.as_str() {
                        "radius" => own(&["sphere", "cylinder"]),
                        _ => own(&["torus"]),
                    };
                    if !applies {
                        let shape = kind.unwrap_or("");
                        self.err(
                            e.key_pos,
                            format!("`{}` does not apply to a {shape}", e.key),
                        );
                        continue;
                    }
                    let x = self.check(v.positive());
                    match e.key.as_str() {
                        "radius" => radius = x,
                        "major" => major = x,
                        _ => minor = x,
                    }
                }
                "color1" => {
                    if let Some(c) = self.check(v.color()) {
                        material.color1 = c;
                    }
                }
                "color2" => {
                    material.color2 = self.check(v.color());
                    color2_pos = Some(e.key_pos);
                }
                "texture" => {
                    if let Some(name) = self.check(v.name()) {
                        self.note_texture(&name, e.value_pos);
                        material.texture = Some(TextureRef {
                            name,
                            pos: e.value_pos,
                        });
                    }
                }
                "mirror" | "reflection" => {
                    if let Some(m) = self.check(v.number_in(0.0, 1.0)) {
                        material.mirror = m;
                    }
                }
                "diffuse" => {
                    if let Some(d) = self.check(v.non_negative()) {
                        material.diffuse = d;
                    }
                }
                "scale" | "rotate" | "translate" => {
                    if let Some(op) = self.check(v.transform_op(&e.key)) {
                        steps.push((op, e.key_pos));
                    }
                }
                _ => {} // "type", handled above
            }
        }
        if let (Some(_), Some(at)) = (&material.texture, color2_pos) {
            self.err(
                at,
                "`color2` makes a checker and `texture` an image map; an object takes one of them",
            );
        }

        let (shape, own_scale) = match kind? {
            "sphere" => (Shape::Sphere, DVec3::splat(radius.unwrap_or(1.0))),
            "plane" => (Shape::Plane, DVec3::ONE),
            "cube" => (Shape::Cube, DVec3::ONE),
            "cone" => (Shape::Cone, DVec3::ONE),
            "cylinder" => {
                let r = radius.unwrap_or(1.0);
                (Shape::Cylinder, DVec3::new(r, 1.0, r))
            }
            "torus" => {
                // The radii stay intrinsic to the shape (the tube is round whatever the ring
                // size); only a ring torus is a solid bounded by its quartic surface.
                let (major, minor) = (major.unwrap_or(1.0), minor.unwrap_or(0.25));
                if !(minor < major) {
                    let at = entries
                        .iter()
                        .find(|e| e.key == "minor" || e.key == "major")
                        .map_or(b.pos, |e| e.key_pos);
                    self.err(
                        at,
                        format!(
                            "a torus needs `minor` < `major` (a ring torus); got major = {major}, \
                             minor = {minor}"
                        ),
                    );
                    return None;
                }
                (Shape::Torus { major, minor }, DVec3::ONE)
            }
            other => {
                self.err(
                    b.pos,
                    format!("type `{other}` is not supported by this build of the tracer"),
                );
                return None;
            }
        };
        // The shape's own size comes first; a singular one is the size key's fault.
        let size_at = entries
            .iter()
            .find(|e| e.key == "radius")
            .map_or(b.pos, |e| e.key_pos);
        let transform =
            self.transform(std::iter::once((TransformOp::Scale(own_scale), size_at)).chain(steps));
        if self.errors.pushed() > errors_before {
            return None;
        }
        Some(ObjectDesc {
            pos: b.pos,
            shape,
            own_scale,
            transform: transform?,
            material,
        })
    }

    fn note_texture(&mut self, name: &str, pos: Pos) {
        if self.textures.iter().any(|t| t == name) {
            return;
        }
        self.textures.push(name.to_string());
        if self.textures.len() == self.limits.max_textures + 1 {
            self.err(
                pos,
                format!(
                    "too many texture files: the limit is {}",
                    self.limits.max_textures
                ),
            );
        }
    }

    fn csg(&mut self, b: &Block, depth: usize) -> Option<CsgDesc> {
        if depth == self.limits.max_csg_depth + 1 {
            self.err(
                b.pos,
                format!(
                    "[CSG] nested too deeply: the limit is {} levels",
                    self.limits.max_csg_depth
                ),
            );
            return None;
        }
        let errors_before = self.errors.pushed();
        let mut op = None;
        let mut steps = Vec::new();
        for e in self.entries(b, CSG_KEYS) {
            let v = Value::new(e);
            match e.key.as_str() {
                "op" => {
                    op = self
                        .check(v.keyword(&["union", "intersection", "difference"], "op"))
                        .map(|k| match k {
                            "union" => CsgOp::Union,
                            "intersection" => CsgOp::Intersection,
                            _ => CsgOp::Difference,
                        });
                }
                _ => {
                    if let Some(op) = self.check(v.transform_op(&e.key)) {
                        steps.push((op, e.key_pos));
                    }
                }
            }
        }
        if !b.broken && !b.entries.iter().any(|e| e.key == "op") {
            self.err(
                b.pos,
                "[CSG] needs `op = union`, `op = intersection` or `op = difference`",
            );
        }
        let mut children = Vec::new();
        let mut child_blocks = 0;
        for c in &b.children {
            if matches!(c.name.as_str(), "object" | "csg") {
                child_blocks += 1;
                if let Some(n) = self.node(c, depth) {
                    children.push(n);
                }
            }
        }
        if child_blocks < 2 && !b.broken {
            self.err(
                b.pos,
                format!(
                    "[CSG] needs two or more [OBJECT] or [CSG] children; it has {child_blocks}"
                ),
            );
        }
        let transform = self.transform(steps);
        if self.errors.pushed() > errors_before {
            return None;
        }
        Some(CsgDesc {
            pos: b.pos,
            op: op?,
            transform: transform?,
            children,
        })
    }

    /// Composes transform steps in the order written; reports the first step at which the
    /// composite stops being finite and invertible.
    fn transform(
        &mut self,
        steps: impl IntoIterator<Item = (TransformOp, Pos)>,
    ) -> Option<Transform> {
        let mut t = Transform::IDENTITY;
        for (op, pos) in steps {
            t = t.then(&Transform::from_op(op));
            if !t.is_valid() {
                self.err(
                    pos,
                    "this transform makes the object's matrix singular or non-finite, or too \
                     close to singular to invert accurately",
                );
                return None;
            }
        }
        Some(t)
    }

    fn check<T>(&mut self, r: Result<T, Diagnostic>) -> Option<T> {
        match r {
            Ok(v) => Some(v),
            Err(d) => {
                self.errors.push(d);
                None
            }
        }
    }
}
