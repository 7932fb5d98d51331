//! The `.ray` parser: items from the lexer → a block tree → a validated [`SceneDesc`].
//!
//! Errors are collected, not thrown: a bad value, an unknown key or a misplaced tag is
//! recorded and parsing goes on with the next item, so one run reports every independent
//! mistake. Only the final result is all-or-nothing.

use std::collections::{HashMap, HashSet};

use glam::DVec3;

use super::lex::{Item, Lexer};
use super::{
    CameraDesc, CsgDesc, CsgOp, Light, Limits, MaterialDesc, Node, ObjectDesc, SceneDesc,
    TextureRef,
};
use crate::diag::{Diagnostic, Found, Pos, SceneError, closest, shorten};
use crate::math::Color;
use crate::sampler::Sampler;
use crate::shape::Shape;
use crate::transform::{Transform, TransformOp};

const TAGS: &[&str] = &[
    "rayfile", "globals", "global", "camera", "light", "object", "csg",
];
const GLOBAL_KEYS: &[&str] = &[
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
const CAMERA_KEYS: &[&str] = &["eye", "look_at", "up", "fov"];
const LIGHT_KEYS: &[&str] = &["position", "color"];
const TRANSFORM_KEYS: &[&str] = &["scale", "rotate", "translate"];
const MATERIAL_KEYS: &[&str] = &[
    "color1",
    "color2",
    "texture",
    "mirror",
    "reflection",
    "diffuse",
];
const OBJECT_KEYS: &[&str] = &[
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
const CSG_KEYS: &[&str] = &["op", "scale", "rotate", "translate"];
const SHAPES: &[&str] = &["sphere", "plane", "cube", "cylinder", "cone", "torus"];
const SAMPLERS: &[&str] = &["center", "thesis", "grid", "jitter", "adaptive"];

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
    let desc = p.scene(&root);
    match p.errors.into_error() {
        None => Ok(desc),
        Some(e) => Err(e),
    }
}

#[derive(Debug)]
struct Entry {
    key: String,
    key_pos: Pos,
    value: String,
    value_pos: Pos,
}

#[derive(Debug)]
struct Block {
    /// Lower-cased tag name; empty for the root.
    name: String,
    pos: Pos,
    entries: Vec<Entry>,
    children: Vec<Block>,
    /// Something inside could not be read (a malformed line, an unclosed child): checks for
    /// missing keys or children would only echo that error, so they are skipped.
    broken: bool,
    /// An unknown tag's block, already reported: its contents are not read, and the next
    /// known tag ends it without another error (see `build_tree`).
    unknown: bool,
    /// For an unknown tag's block, the known tag it was likely meant to be.
    hint: Option<&'static str>,
}

impl Block {
    fn new(name: String, pos: Pos) -> Self {
        Block {
            name,
            pos,
            entries: Vec::new(),
            children: Vec::new(),
            broken: false,
            unknown: false,
            hint: None,
        }
    }

    fn display(&self) -> String {
        format!("[{}]", self.name.to_ascii_uppercase())
    }
}

/// Most `key = value` lines one block may hold: far more than any block's keys, and room for
/// a long chain of transforms.
pub const MAX_BLOCK_ENTRIES: usize = 4_096;

/// Where the reading of a file stops (see `build_tree`), from the scene's limits.
struct Caps {
    /// Blocks open at once.
    depth: usize,
    /// `[OBJECT]` tags.
    objects: usize,
    /// Blocks of any kind.
    blocks: usize,
}

impl Caps {
    fn of(limits: &Limits) -> Caps {
        Caps {
            // `[rayfile]`, the CSG levels and the `[OBJECT]` inside the deepest, and room for
            // a few levels more, which the CSG check then reports as such.
            depth: limits.max_csg_depth + 8,
            objects: limits.max_objects,
            // A [CSG] holds two objects at least, so a file within the limits has fewer
            // blocks than this; past it, [LIGHT] or [CSG] blocks alone would fill the tree.
            blocks: limits
                .max_objects
                .saturating_mul(2)
                .saturating_add(limits.max_lights)
                .saturating_add(16),
        }
    }
}

/// The error that ends the reading at `item`, if it passes one of `caps` (`object_tags` and
/// `blocks` opened so far).
fn limit_passed(
    item: &Item,
    stack: &[Block],
    object_tags: usize,
    blocks: usize,
    caps: &Caps,
) -> Option<Diagnostic> {
    let message = match item {
        Item::Tag { close: false, .. } if stack.len() > caps.depth => {
            format!("blocks nested more than {} deep", caps.depth)
        }
        Item::Tag {
            name, close: false, ..
        } if name == "object" && object_tags == caps.objects => {
            format!("too many objects: the limit is {}", caps.objects)
        }
        Item::Tag { close: false, .. } if blocks >= caps.blocks => format!(
            "more than {} blocks, more than a scene within the limits can have",
            caps.blocks
        ),
        // `>=`: a `[rayfile]` wrapper's entries join its parent's all at once.
        Item::Entry { .. } if stack.last()?.entries.len() >= MAX_BLOCK_ENTRIES => {
            let block = match stack {
                [_root] => "no block".to_string(),
                _ => stack.last()?.display(),
            };
            format!("more than {MAX_BLOCK_ENTRIES} lines in {block}")
        }
        _ => return None,
    };
    let pos = match item {
        Item::Tag { pos, .. } => *pos,
        Item::Entry { key_pos, .. } => *key_pos,
        Item::Broken => return None,
    };
    Some(Diagnostic::new(
        pos,
        format!("{message}; the rest of the file is not read"),
    ))
}

/// Nests items into blocks by their tags, reporting unknown, misplaced, unmatched and
/// unclosed tags. The returned root holds the top-level blocks (a `[rayfile]` wrapper is
/// unwrapped) and any entries written outside every block.
///
/// A misspelt tag is one mistake and gets one error. An unknown opening tag (`[OBJCET]`)
/// opens a block that the next known tag ends, silently: an opening one (the block was
/// likely never meant to hold it), or a closing one that matches nothing open (most likely
/// the closer of the misspelt opener, `[/OBJECT]`); the unknown name's own closer, and the
/// closer of the known tag it was taken for (`[CSGG]`'s `[/CSG]`), are then not reported
/// wherever they come. An unknown closing tag (`[/OBJCET]`) whose nearest known name is the
/// innermost open block's is reported and closes that block, even if the same misspelling
/// opened an unknown block before. Without these rules, one typo produced three more
/// errors, one of them asking for `[/OBJCET]` and one blaming the next, correct block.
///
/// The tree holds the whole file before it is read for meaning, some hundreds of bytes an
/// entry, so what it may hold is bounded here, where the file is read: past `caps.objects`
/// `[OBJECT]` tags (2,000,000 spheres, 62 MB, took 2 GB to be refused as too many),
/// `caps.blocks` blocks of any kind (as many `[LIGHT]` or `[CSG]` blocks took as much) or
/// [`MAX_BLOCK_ENTRIES`] lines in one block (7,000,000 `scale = 1` lines on one sphere took
/// 1.4 GB, and were accepted), the reading stops with that error.
///
/// At most `caps.depth` blocks are open at once: a tag that would open one more is an error
/// and ends the reading there. Everything that walks the tree (the checks, and dropping it)
/// recurses once per level, so an unbounded nesting (100,000 `[CSG]` tags: 600 KB) would
/// overflow the stack and abort the process, the service's included.
fn build_tree(mut items: Lexer<'_>, errors: &mut Found, caps: Caps) -> Block {
    let mut object_tags = 0usize;
    let mut blocks = 0usize;
    let mut stack: Vec<Block> = vec![Block::new(String::new(), Pos::new(1, 1))];
    // Unknown opening tags' names, whose closers are then not reported again.
    let mut unknown_names: HashSet<String> = HashSet::new();
    // The known tags those unknown openers were taken for (`[CSGG]`: `csg`), whose closers
    // (`[/CSG]`) are then not reported as closing nothing: counted, each standing for one
    // closer still to come and silencing one.
    let mut unknown_hints: HashMap<&'static str, usize> = HashMap::new();
    let mut seen_rayfile = false;
    let mut seen_anything = false;
    let mut stopped = false;
    // Where `[/rayfile]` closed the wrapper, until something after it has been reported.
    let mut rayfile_closed: Option<Pos> = None;
    while let Some(item) = items.next(errors) {
        if let (Some(closed), Item::Tag { pos, .. } | Item::Entry { key_pos: pos, .. }) =
            (rayfile_closed, &item)
        {
            errors.push(Diagnostic::new(
                *pos,
                format!(
                    "the scene goes on after [/rayfile] (line {}), which must end it",
                    closed.line
                ),
            ));
            rayfile_closed = None;
        }
        if let Some(stop) = limit_passed(&item, &stack, object_tags, blocks, &caps) {
            errors.push(stop);
            stopped = true;
            break;
        }
        match item {
            Item::Tag {
                name,
                close: false,
                pos,
            } => {
                if name == "object" {
                    object_tags += 1;
                }
                blocks += 1;
                let known = TAGS.contains(&name.as_str());
                let suggestion = if known {
                    end_unknown(&mut stack);
                    None
                } else {
                    closest(&name, TAGS.iter().copied())
                };
                let parent = stack.last().map(|b| b.name.as_str()).unwrap_or("");
                if !known {
                    if let Some(s) = suggestion {
                        *unknown_hints.entry(s).or_default() += 1;
                    }
                    let hint = match suggestion {
                        Some(s) => format!("; did you mean [{}]?", s.to_ascii_uppercase()),
                        None => {
                            "; expected [GLOBALS], [CAMERA], [LIGHT], [OBJECT] or [CSG]".to_string()
                        }
                    };
                    errors.push(Diagnostic::new(
                        pos,
                        format!(
                            "unknown tag [{}]{hint}",
                            shorten(&name.to_ascii_uppercase())
                        ),
                    ));
                    unknown_names.insert(name.clone());
                } else if name == "rayfile" {
                    if seen_rayfile || seen_anything || stack.len() > 1 {
                        errors.push(Diagnostic::new(
                            pos,
                            "[rayfile] may only wrap the whole file, once, as its first tag",
                        ));
                    }
                    seen_rayfile = true;
                } else {
                    let allowed = match name.as_str() {
                        "object" | "csg" => matches!(parent, "" | "rayfile" | "csg"),
                        _ => matches!(parent, "" | "rayfile"),
                    };
                    if !allowed {
                        errors.push(Diagnostic::new(
                            pos,
                            format!(
                                "[{}] cannot appear inside [{}]; close [/{}] first",
                                name.to_ascii_uppercase(),
                                parent.to_ascii_uppercase(),
                                parent.to_ascii_uppercase()
                            ),
                        ));
                    }
                }
                seen_anything = true;
                let mut block = Block::new(name, pos);
                block.unknown = !known;
                block.hint = suggestion;
                stack.push(block);
            }
            Item::Tag {
                name,
                close: true,
                pos,
            } => {
                let open_at = stack
                    .iter()
                    .skip(1)
                    .rposition(|b| same_block(&b.name, &name));
                let Some(depth) = open_at else {
                    let top = stack.len() - 1;
                    let hint = closest(&name, TAGS.iter().copied());
                    // A misspelling of the innermost block's own closer.
                    let closes_top = top > 0 && hint == Some(stack[top].name.as_str());
                    if TAGS.contains(&name.as_str()) {
                        // The closer of a misspelt opener: of the one still open, or of one
                        // a known tag has ended since. Each silences one closer, not all.
                        let silenced = match end_unknown(&mut stack) {
                            Some(hint) => {
                                forget_one(&mut unknown_hints, hint);
                                true
                            }
                            None => forget_one(&mut unknown_hints, Some(name.as_str())),
                        };
                        if !silenced {
                            errors.push(Diagnostic::new(
                                pos,
                                format!(
                                    "[/{0}] closes nothing: no [{0}] is open",
                                    name.to_ascii_uppercase()
                                ),
                            ));
                        }
                    } else if closes_top || !unknown_names.contains(&name) {
                        // A misspelt closer is reported even if the same misspelling opened
                        // an unknown block earlier, when it may close the innermost block.
                        errors.push(Diagnostic::new(
                            pos,
                            match hint {
                                Some(s) => format!(
                                    "unknown tag [/{}]; did you mean [/{}]?",
                                    shorten(&name.to_ascii_uppercase()),
                                    s.to_ascii_uppercase()
                                ),
                                None => format!(
                                    "unknown tag [/{}]",
                                    shorten(&name.to_ascii_uppercase())
                                ),
                            },
                        ));
                        // The innermost block's own closer, misspelt: it ends that block.
                        if closes_top {
                            close_top(&mut stack, &mut rayfile_closed, pos);
                        }
                    }
                    continue;
                };
                let depth = depth + 1;
                while stack.len() > depth + 1 {
                    let Some(open) = stack.pop() else { break };
                    if !open.unknown {
                        errors.push(unclosed(&open, Some(pos)));
                    }
                    attach(&mut stack, open);
                    if let Some(parent) = stack.last_mut() {
                        parent.broken = true;
                    }
                }
                // An unknown block closed by its own closer: its hint has had its closer.
                if let Some(top) = stack.last().filter(|b| b.unknown) {
                    forget_one(&mut unknown_hints, top.hint);
                }
                close_top(&mut stack, &mut rayfile_closed, pos);
            }
            Item::Broken => {
                if let Some(top) = stack.last_mut() {
                    top.broken = true;
                }
            }
            Item::Entry {
                key,
                key_pos,
                value,
                value_pos,
            } => {
                seen_anything = true;
                if let Some(top) = stack.last_mut() {
                    top.entries.push(Entry {
                        key,
                        key_pos,
                        value,
                        value_pos,
                    });
                }
            }
        }
    }
    while stack.len() > 1 {
        let Some(mut open) = stack.pop() else { break };
        if stopped || open.unknown {
            // Not read to its end: its closing tag may well be in the part not read.
            open.broken = true;
        } else {
            errors.push(unclosed(&open, None));
        }
        attach(&mut stack, open);
    }
    stack
        .pop()
        .unwrap_or_else(|| Block::new(String::new(), Pos::new(1, 1)))
}

/// Ends the innermost block at its closing tag at `pos`.
fn close_top(stack: &mut Vec<Block>, rayfile_closed: &mut Option<Pos>, pos: Pos) {
    if let Some(done) = stack.pop() {
        if done.name == "rayfile" && stack.len() == 1 {
            *rayfile_closed = Some(pos);
        }
        attach(stack, done);
    }
}

/// Ends the innermost block if it is an unknown tag's (reported when it opened); its parent
/// is marked broken, since what the block swallowed may have been the parent's. Returns the
/// ended block's hint (`Some`) if there was one.
fn end_unknown(stack: &mut Vec<Block>) -> Option<Option<&'static str>> {
    if stack.len() < 2 || !stack[stack.len() - 1].unknown {
        return None;
    }
    let open = stack.pop()?;
    let hint = open.hint;
    attach(stack, open);
    if let Some(parent) = stack.last_mut() {
        parent.broken = true;
    }
    Some(hint)
}

/// Whether a closing tag named `close` ends the block opened as `open`: by name, with
/// `[GLOBAL]` and `[GLOBALS]` one block (SCENE.md accepts either), so that `[GLOBALS]` …
/// `[/GLOBAL]` is a block and not "closes nothing".
fn same_block(open: &str, close: &str) -> bool {
    open == close || (matches!(open, "global" | "globals") && matches!(close, "global" | "globals"))
}

/// Takes one pending closer of `hint` off the count; whether there was one.
fn forget_one(pending: &mut HashMap<&'static str, usize>, hint: Option<&str>) -> bool {
    match hint.and_then(|h| pending.get_mut(h)) {
        Some(n) if *n > 0 => {
            *n -= 1;
            true
        }
        _ => false,
    }
}

/// Adds a finished block to its parent; a `[rayfile]` wrapper is dissolved into it.
fn attach(stack: &mut [Block], block: Block) {
    let Some(parent) = stack.last_mut() else {
        return;
    };
    if block.name == "rayfile" {
        parent.entries.extend(block.entries);
        parent.children.extend(block.children);
    } else {
        parent.children.push(block);
    }
}

fn unclosed(block: &Block, at: Option<Pos>) -> Diagnostic {
    let name = block.name.to_ascii_uppercase();
    let message = match at {
        Some(p) => format!(
            "[{name}] is not closed: expected [/{name}] before line {}",
            p.line
        ),
        None => format!("[{name}] is not closed: expected [/{name}] before the end of the file"),
    };
    Diagnostic::new(block.pos, message)
}

struct Parser<'a> {
    errors: Found,
    limits: &'a Limits,
    textures: Vec<String>,
    /// Where each light of the scene was written, in the order they are counted.
    light_pos: Vec<Pos>,
}

/// Which block kinds a key belongs to, for "`fov` belongs in [CAMERA]" hints.
fn home_of(key: &str) -> Option<&'static str> {
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

    fn scene(&mut self, root: &Block) -> SceneDesc {
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
            objects: Vec::new(),
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
        for b in &root.children {
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
        // not the scene's fault (it read "the default image size 640×4" for `width = 101`).
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

/// A value to interpret, with its position for error messages.
struct Value<'a> {
    text: &'a str,
    pos: Pos,
    key: &'a str,
}

impl<'a> Value<'a> {
    fn new(e: &'a Entry) -> Self {
        Value {
            text: e.value.as_str(),
            pos: e.value_pos,
            key: e.key.as_str(),
        }
    }

    fn fail<T>(&self, expected: &str) -> Result<T, Diagnostic> {
        let found = if self.text.is_empty() {
            "nothing".to_string()
        } else {
            format!("`{}`", shorten(self.text))
        };
        Err(Diagnostic::new(
            self.pos,
            format!("`{}`: expected {expected}, found {found}", self.key),
        ))
    }

    fn at(&self, offset_chars: usize, message: String) -> Diagnostic {
        let col = self
            .pos
            .column
            .saturating_add(u32::try_from(offset_chars).unwrap_or(0));
        Diagnostic::new(Pos::new(self.pos.line, col), message)
    }

    fn number(&self) -> Result<f64, Diagnostic> {
        parse_f64(self.text).or_else(|e| self.fail(e.expected()))
    }

    fn number_in(&self, lo: f64, hi: f64) -> Result<f64, Diagnostic> {
        let x = self.number()?;
        if (lo..=hi).contains(&x) {
            Ok(x)
        } else {
            self.fail(&format!("a number from {lo} to {hi}"))
        }
    }

    fn number_open(&self, lo: f64, hi: f64) -> Result<f64, Diagnostic> {
        let x = self.number()?;
        if x > lo && x < hi {
            Ok(x)
        } else {
            self.fail(&format!("a number between {lo} and {hi}, exclusive"))
        }
    }

    fn positive(&self) -> Result<f64, Diagnostic> {
        let x = self.number()?;
        if x > 0.0 {
            Ok(x)
        } else {
            self.fail("a number greater than 0")
        }
    }

    fn non_negative(&self) -> Result<f64, Diagnostic> {
        let x = self.number()?;
        if x >= 0.0 {
            Ok(x)
        } else {
            self.fail("a number ≥ 0")
        }
    }

    fn whole(&self, lo: u32, hi: u32) -> Result<u32, Diagnostic> {
        let expected = format!("a whole number from {lo} to {hi}");
        match self.text.parse::<u64>() {
            Ok(n) if n >= u64::from(lo) && n <= u64::from(hi) => Ok(n as u32),
            _ => self.fail(&expected),
        }
    }

    fn flag(&self) -> Result<bool, Diagnostic> {
        match self.text.to_ascii_lowercase().as_str() {
            "on" | "yes" | "true" => Ok(true),
            "off" | "no" | "false" => Ok(false),
            _ => self.fail("on, off, yes, no, true or false"),
        }
    }

    fn keyword(&self, options: &[&'static str], what: &str) -> Result<&'static str, Diagnostic> {
        let word = self.text.to_ascii_lowercase();
        if let Some(k) = options.iter().find(|o| **o == word) {
            return Ok(k);
        }
        let hint = match closest(&word, options.iter().copied()) {
            Some(s) => format!("; did you mean `{s}`?"),
            None => String::new(),
        };
        Err(Diagnostic::new(
            self.pos,
            format!(
                "unknown {what} `{}`: expected one of {}{hint}",
                shorten(self.text),
                options.join(", ")
            ),
        ))
    }

    fn name(&self) -> Result<String, Diagnostic> {
        let t = self.text;
        if let Some(rest) = t.strip_prefix('"') {
            return match rest.strip_suffix('"') {
                Some(inner) if !inner.is_empty() && !inner.contains('"') => Ok(inner.to_string()),
                _ => self.fail("a file name, bare or in double quotes"),
            };
        }
        if t.is_empty() || t.chars().any(char::is_whitespace) || t.contains('"') {
            return self.fail("a file name (put a name with spaces in double quotes)");
        }
        Ok(t.to_string())
    }

    /// `<a, b, c>` with finite components.
    fn vector(&self) -> Result<DVec3, Diagnostic> {
        const EXPECTED: &str = "a vector like <1, 0, 0>";
        let t = self.text;
        let (Some(inner), true) = (t.strip_prefix('<'), t.ends_with('>')) else {
            return self.fail(EXPECTED);
        };
        let inner = &inner[..inner.len() - 1];
        // `<>` has no components (split, it is one empty one).
        let parts: Vec<&str> = if inner.trim().is_empty() {
            Vec::new()
        } else {
            inner.split(',').collect()
        };
        if parts.len() != 3 {
            // Say why the count is off where a reader would not see it: components written
            // with spaces and no commas, or a comma at the end.
            let why = if parts.len() < 3 && parts.iter().any(|p| p.split_whitespace().count() > 1) {
                " (components are separated by commas)"
            } else if parts.len() > 3 && parts.last().is_some_and(|p| p.trim().is_empty()) {
                " (the last is empty: a comma at the end?)"
            } else {
                ""
            };
            return Err(Diagnostic::new(
                self.pos,
                format!(
                    "`{}`: expected {EXPECTED} with three components, found {}{why}",
                    self.key,
                    parts.len()
                ),
            ));
        }
        let mut v = [0.0; 3];
        let mut offset = 1; // past '<', in characters
        for (i, part) in parts.iter().enumerate() {
            let lead = part.chars().take_while(|c| c.is_whitespace()).count();
            match parse_f64(part.trim()) {
                Ok(x) => v[i] = x,
                Err(e) => {
                    let expected = match e {
                        BadNumber::NotANumber => "a number",
                        BadNumber::TooLarge => e.expected(),
                    };
                    return Err(self.at(
                        offset + lead,
                        format!(
                            "`{}`: component {} of the vector: expected {expected}, found `{}`",
                            self.key,
                            i + 1,
                            shorten(part.trim())
                        ),
                    ));
                }
            }
            offset += part.chars().count() + 1;
        }
        Ok(DVec3::from_array(v))
    }

    /// A colour: one number `c` (meaning `<c, c, c>`) or a vector, components ≥ 0.
    fn color(&self) -> Result<Color, Diagnostic> {
        let c = if self.text.starts_with('<') {
            self.vector()?
        } else {
            match parse_f64(self.text) {
                Ok(x) => Color::splat(x),
                Err(BadNumber::NotANumber) => {
                    return self.fail("a colour: a number or a vector like <1, 0.5, 0>");
                }
                Err(e) => return self.fail(e.expected()),
            }
        };
        if c.min_element() < 0.0 {
            return self.fail("a colour with components ≥ 0");
        }
        Ok(c)
    }

    fn transform_op(&self, key: &str) -> Result<TransformOp, Diagnostic> {
        match key {
            "scale" => {
                let s = if self.text.starts_with('<') {
                    self.vector()?
                } else {
                    match parse_f64(self.text) {
                        Ok(x) => DVec3::splat(x),
                        Err(BadNumber::NotANumber) => {
                            return self.fail("a number or a vector like <1, 2, 1>");
                        }
                        Err(e) => return self.fail(e.expected()),
                    }
                };
                if s.x == 0.0 || s.y == 0.0 || s.z == 0.0 {
                    return self.fail("a scale with no zero component");
                }
                Ok(TransformOp::Scale(s))
            }
            "rotate" => Ok(TransformOp::Rotate(self.vector()?)),
            _ => Ok(TransformOp::Translate(self.vector()?)),
        }
    }
}

/// Largest magnitude of a number in a scene. Far beyond any scene's scale (a kilometre in
/// micrometres is 1e9), and small enough that what the tracer computes from a few numbers
/// stays finite: a distance squared, a colour times a light's colour times a texel, summed
/// over every light. A light at 1e154 squared its distance to infinity and lit nothing;
/// colours of 1e308 summed to infinity, and `0·∞ = NaN` came out as a white pixel; an eye at
/// 1e160 was reported as "`up` parallel to the view".
pub const MAX_NUMBER: f64 = 1e15;

/// Why a value is not a scene number.
#[derive(Debug, Clone, Copy, PartialEq)]
enum BadNumber {
    NotANumber,
    TooLarge,
}

impl BadNumber {
    /// What was expected, for a message.
    fn expected(self) -> &'static str {
        match self {
            BadNumber::NotANumber => "a number like 1.5 or -2e3",
            BadNumber::TooLarge => "a number of magnitude at most 1e15",
        }
    }
}

/// A finite decimal number of magnitude at most [`MAX_NUMBER`]. Rust's parser also takes
/// `inf`, `NaN` and `infinity`; the format does not.
fn parse_f64(s: &str) -> Result<f64, BadNumber> {
    if !s
        .chars()
        .all(|c| c.is_ascii_digit() || matches!(c, '+' | '-' | '.' | 'e' | 'E'))
    {
        return Err(BadNumber::NotANumber);
    }
    let x = s.parse::<f64>().map_err(|_| BadNumber::NotANumber)?;
    // Only digits, signs, points and exponents got here, so an infinite value is a literal
    // too large for an `f64` (`1e400`), not `inf`.
    if x.abs() > MAX_NUMBER {
        return Err(BadNumber::TooLarge);
    }
    Ok(x)
}

/// Which of `width` and `height` a scene's [GLOBALS] gave, and whether either was refused:
/// the default size is checked against the limits only where it stands for a size not given.
#[derive(Debug, Default, Clone, Copy)]
struct GivenSize {
    width: bool,
    height: bool,
    refused: bool,
}
