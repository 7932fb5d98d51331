//! Line lexer for `.ray` files: splits the text into tags and `key = value` items, each with
//! its position. It knows nothing about which tags or keys exist; that is the parser's job.

use crate::diag::{Diagnostic, Found, Pos, shorten};

/// One meaningful line of a scene file.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Item {
    /// `[NAME]` (open) or `[/NAME]` (close); the name is lower-cased.
    Tag { name: String, close: bool, pos: Pos },
    /// A line that could not be read (its diagnostic is in the error list). Kept so the
    /// parser knows the enclosing block is incomplete and does not pile on follow-up errors.
    Broken,
    /// `key = value`; the key is lower-cased, the value is kept as written (trimmed).
    Entry {
        key: String,
        key_pos: Pos,
        value: String,
        value_pos: Pos,
    },
}

/// The longest line read, in bytes. A scene's lines are a tag or one `key = value`; a longer
/// one is a file that is not a scene (a binary, a minified dump), and each line is widened to
/// 4-byte `char`s to be read, so without a cap one 100 MB line would cost 400 MB before its
/// first character is refused.
pub(crate) const MAX_LINE_BYTES: usize = 64 * 1024;

/// Reads a scene line by line, as the parser asks for the next item: the file is never
/// held as a list of items (for a file of millions of short lines such a list is many times
/// the file's size), and the parser may stop reading where a limit is passed.
pub(crate) struct Lexer<'a> {
    lines: std::iter::Enumerate<std::str::Lines<'a>>,
}

impl<'a> Lexer<'a> {
    pub(crate) fn new(source: &'a str) -> Self {
        Lexer {
            lines: source.lines().enumerate(),
        }
    }

    /// The next item. Lines that are neither blank, a comment, a tag nor an entry become
    /// diagnostics (and a [`Item::Broken`]), so that every such line is reported.
    pub(crate) fn next(&mut self, errors: &mut Found) -> Option<Item> {
        for (index, raw) in self.lines.by_ref() {
            if let Some(item) = lex_line(index, raw, errors) {
                return Some(item);
            }
        }
        None
    }
}

/// Every item of `source`, with its diagnostics (the tests' view of the lexer).
#[cfg(test)]
pub(crate) fn lex(source: &str) -> (Vec<Item>, Found) {
    let mut errors = Found::default();
    let mut lexer = Lexer::new(source);
    let mut items = Vec::new();
    while let Some(item) = lexer.next(&mut errors) {
        items.push(item);
    }
    (items, errors)
}

/// The item of line `index` (0-based), `None` for a blank or comment line.
fn lex_line(index: usize, raw: &str, errors: &mut Found) -> Option<Item> {
    let line = u32::try_from(index + 1).unwrap_or(u32::MAX);
    if raw.len() > MAX_LINE_BYTES {
        errors.push(Diagnostic::new(
            Pos::new(line, 1),
            format!(
                "a line of {} bytes: a scene's lines are a tag or one `key = value` \
                 (at most {MAX_LINE_BYTES} bytes)",
                raw.len()
            ),
        ));
        return Some(Item::Broken);
    }
    let chars: Vec<char> = raw.chars().collect();
    let end = comment_start(&chars);
    let text = &chars[..end];
    // A blank or comment line is no item.
    let first = text.iter().position(|c| !c.is_whitespace())?;
    let last = text
        .iter()
        .rposition(|c| !c.is_whitespace())
        .unwrap_or(first);
    let body = &text[first..=last];
    let col = |i: usize| u32::try_from(i + 1).unwrap_or(u32::MAX);
    let pos = Pos::new(line, col(first));

    if body[0] == '[' {
        return Some(match lex_tag(body) {
            Ok((name, close)) => Item::Tag { name, close, pos },
            Err(msg) => {
                errors.push(Diagnostic::new(pos, msg));
                Item::Broken
            }
        });
    }
    let Some(eq) = body.iter().position(|&c| c == '=') else {
        errors.push(Diagnostic::new(
            pos,
            "expected `key = value` or a tag such as [OBJECT]",
        ));
        return Some(Item::Broken);
    };
    let key: String = body[..eq]
        .iter()
        .collect::<String>()
        .trim()
        .to_ascii_lowercase();
    if key.is_empty() {
        errors.push(Diagnostic::new(pos, "expected a key before `=`"));
        return Some(Item::Broken);
    }
    if let Some(bad) = key
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || *c == '_'))
    {
        errors.push(Diagnostic::new(
            pos,
            format!(
                "a key is letters, digits and `_`; found `{bad}` in `{}`",
                shorten(&key)
            ),
        ));
        return Some(Item::Broken);
    }
    let rest = &body[eq + 1..];
    let value_offset = rest.iter().position(|c| !c.is_whitespace());
    let (value, value_pos) = match value_offset {
        Some(off) => (
            rest[off..].iter().collect::<String>(),
            Pos::new(line, col(first + eq + 1 + off)),
        ),
        None => (String::new(), Pos::new(line, col(first + eq + 1))),
    };
    Some(Item::Entry {
        key,
        key_pos: pos,
        value,
        value_pos,
    })
}

/// Index where a `#` comment starts (outside double quotes), or the line length.
fn comment_start(chars: &[char]) -> usize {
    let mut quoted = false;
    for (i, &c) in chars.iter().enumerate() {
        match c {
            '"' => quoted = !quoted,
            '#' if !quoted => return i,
            _ => {}
        }
    }
    chars.len()
}

fn lex_tag(body: &[char]) -> Result<(String, bool), String> {
    if body.last() != Some(&']') {
        return Err("a tag is `[NAME]` or `[/NAME]` alone on its line".into());
    }
    let inner: String = body[1..body.len() - 1].iter().collect();
    let inner = inner.trim();
    let (close, name) = match inner.strip_prefix('/') {
        Some(n) => (true, n.trim()),
        None => (false, inner),
    };
    if name.is_empty() || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(format!(
            "`[{}]` is not a tag: expected a name such as [OBJECT]",
            shorten(inner)
        ));
    }
    Ok((name.to_ascii_lowercase(), close))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lexes_tags_entries_comments_and_positions() {
        let src = "[rayfile] # wrapper\n\n  Radius= 5.25\ntexture = \"a#b.png\" # c\n[/Object]\n";
        let (items, errors) = lex(src);
        assert_eq!(errors.pushed(), 0, "{errors:?}");
        assert_eq!(
            items,
            vec![
                Item::Tag {
                    name: "rayfile".into(),
                    close: false,
                    pos: Pos::new(1, 1)
                },
                Item::Entry {
                    key: "radius".into(),
                    key_pos: Pos::new(3, 3),
                    value: "5.25".into(),
                    value_pos: Pos::new(3, 11)
                },
                Item::Entry {
                    key: "texture".into(),
                    key_pos: Pos::new(4, 1),
                    value: "\"a#b.png\"".into(),
                    value_pos: Pos::new(4, 11)
                },
                Item::Tag {
                    name: "object".into(),
                    close: true,
                    pos: Pos::new(5, 1)
                },
            ]
        );
    }

    #[test]
    fn reports_every_malformed_line() {
        let (_, errors) = lex("radius 5\n[OBJ ECT]\n= 3\n[OBJECT\n");
        let lines: Vec<u32> = errors.kept().iter().map(|e| e.pos.line).collect();
        assert_eq!(lines, vec![1, 2, 3, 4]);
    }

    #[test]
    fn columns_count_characters_not_bytes() {
        let (items, _) = lex("# é\n  é = 1\n");
        // `é` is not a valid key character, so the line is an error at column 3.
        assert_eq!(items, vec![Item::Broken]);
        let (_, errors) = lex("  é = 1\n");
        assert_eq!(errors.kept()[0].pos, Pos::new(1, 3));
        let (items, _) = lex("ambient = 0.5 # é\n");
        assert!(matches!(&items[0], Item::Entry { value, .. } if value == "0.5"));
    }
}
