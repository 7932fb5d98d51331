//! The block tree: the lexer's items grouped into `[TAG] … [/TAG]` blocks of key-value
//! entries, with misplaced, unclosed and unknown tags reported and skipped so that parsing
//! goes on. Entry counts and nesting are capped by [`super::Limits`] and
//! [`MAX_BLOCK_ENTRIES`]; what the keys mean is [`super::parse`]'s business.

use std::collections::{HashMap, HashSet};

use super::Limits;
use super::lex::{Item, Lexer};
use crate::diag::{Diagnostic, Found, Pos, closest, shorten};

pub(super) const TAGS: &[&str] = &[
    "rayfile", "globals", "global", "camera", "light", "object", "csg",
];

#[derive(Debug)]
pub(super) struct Entry {
    pub(super) key: String,
    pub(super) key_pos: Pos,
    pub(super) value: String,
    pub(super) value_pos: Pos,
}

#[derive(Debug)]
pub(super) struct Block {
    /// Lower-cased tag name; empty for the root.
    pub(super) name: String,
    pub(super) pos: Pos,
    pub(super) entries: Vec<Entry>,
    pub(super) children: Vec<Block>,
    /// Something inside could not be read (a malformed line, an unclosed child): checks for
    /// missing keys or children would only echo that error, so they are skipped.
    pub(super) broken: bool,
    /// An unknown tag's block, already reported: its contents are not read, and the next
    /// known tag ends it without another error (see `build_tree`).
    pub(super) unknown: bool,
    /// For an unknown tag's block, the known tag it was likely meant to be.
    pub(super) hint: Option<&'static str>,
}

impl Block {
    pub(super) fn new(name: String, pos: Pos) -> Self {
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

    pub(super) fn display(&self) -> String {
        format!("[{}]", self.name.to_ascii_uppercase())
    }
}

/// Most `key = value` lines one block may hold: far more than any block's keys, and room for
/// a long chain of transforms.
pub const MAX_BLOCK_ENTRIES: usize = 4_096;

/// Where the reading of a file stops (see `build_tree`), from the scene's limits.
pub(super) struct Caps {
    /// Blocks open at once.
    pub(super) depth: usize,
    /// `[OBJECT]` tags.
    pub(super) objects: usize,
    /// Blocks of any kind.
    pub(super) blocks: usize,
}

impl Caps {
    pub(super) fn of(limits: &Limits) -> Caps {
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
pub(super) fn limit_passed(
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
/// opened an unknown block before. Without these rules, one typo would produce three more
/// errors, one of them asking for `[/OBJCET]` and one blaming the next, correct block.
///
/// The tree holds the whole file before it is read for meaning, some hundreds of bytes an
/// entry, so what it may hold is bounded here, where the file is read: past `caps.objects`
/// `[OBJECT]` tags, `caps.blocks` blocks of any kind or [`MAX_BLOCK_ENTRIES`] lines in one
/// block, the reading stops with that error: a file of millions of tiny blocks or lines
/// would otherwise hold gigabytes before a count could refuse it.
///
/// At most `caps.depth` blocks are open at once: a tag that would open one more is an error
/// and ends the reading there. Everything that walks the tree (the checks, and dropping it)
/// recurses once per level, so an unbounded nesting (100,000 `[CSG]` tags: 600 KB) would
/// overflow the stack and abort the process, the service's included.
pub(super) fn build_tree(mut items: Lexer<'_>, errors: &mut Found, caps: Caps) -> Block {
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
pub(super) fn close_top(stack: &mut Vec<Block>, rayfile_closed: &mut Option<Pos>, pos: Pos) {
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
pub(super) fn end_unknown(stack: &mut Vec<Block>) -> Option<Option<&'static str>> {
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
pub(super) fn same_block(open: &str, close: &str) -> bool {
    open == close || (matches!(open, "global" | "globals") && matches!(close, "global" | "globals"))
}

/// Takes one pending closer of `hint` off the count; whether there was one.
pub(super) fn forget_one(pending: &mut HashMap<&'static str, usize>, hint: Option<&str>) -> bool {
    match hint.and_then(|h| pending.get_mut(h)) {
        Some(n) if *n > 0 => {
            *n -= 1;
            true
        }
        _ => false,
    }
}

/// Adds a finished block to its parent; a `[rayfile]` wrapper is dissolved into it. A
/// finished block's lists are cut to their length: a scene of many small blocks would
/// otherwise hold room for four entries in each (a growing list's first size).
pub(super) fn attach(stack: &mut [Block], mut block: Block) {
    let Some(parent) = stack.last_mut() else {
        return;
    };
    block.entries.shrink_to_fit();
    block.children.shrink_to_fit();
    if block.name == "rayfile" {
        parent.entries.extend(block.entries);
        parent.children.extend(block.children);
    } else {
        parent.children.push(block);
    }
}

pub(super) fn unclosed(block: &Block, at: Option<Pos>) -> Diagnostic {
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
