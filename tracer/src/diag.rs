//! Diagnostics: positioned error messages about a scene file.
//!
//! Every problem the parser or the scene builder finds becomes a [`Diagnostic`] that names a
//! 1-based line and column (counted in characters, as editors show them) and says what was
//! expected. A [`SceneError`] carries all the diagnostics found in one pass, so a user fixes
//! several mistakes per round trip. This module formats them; it does not find them, with
//! one exception that comes before any parsing: [`scene_text`], which refuses a file that is
//! not UTF-8 at its first bad byte.

use std::fmt;

/// A position in a scene file: 1-based line and column (in characters).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Pos {
    /// Line, from 1.
    pub line: u32,
    /// Column in characters, from 1.
    pub column: u32,
}

impl Pos {
    /// A position at `line` and `column` (both from 1).
    pub const fn new(line: u32, column: u32) -> Self {
        Pos { line, column }
    }
}

impl fmt::Display for Pos {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.line, self.column)
    }
}

/// One problem in a scene, at a position.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Diagnostic {
    /// Where the problem is.
    pub pos: Pos,
    /// What is wrong, in one line.
    pub message: String,
}

impl Diagnostic {
    /// A message at `pos`. Messages quote the scene's own text, which may hold control
    /// characters (a NUL, an escape sequence that would restyle a terminal) or invisible
    /// ones (a zero-width space pasted from a web page, a byte-order mark in mid-file):
    /// those are written as escapes (`\0`, `\u{1b}`, `\u{200b}`), so a message is always
    /// one line of plain text that shows every character it quotes.
    pub fn new(pos: Pos, message: impl Into<String>) -> Self {
        let mut message = message.into();
        if message.contains(|c: char| c.is_control() || is_invisible(c)) {
            let mut plain = String::with_capacity(message.len() + 8);
            for c in message.chars() {
                if c.is_control() {
                    plain.extend(c.escape_debug());
                } else if is_invisible(c) {
                    plain.extend(c.escape_unicode());
                } else {
                    plain.push(c);
                }
            }
            message = plain;
        }
        Diagnostic { pos, message }
    }
}

/// Characters that print as nothing: Unicode's format characters (category Cf: zero-width
/// spaces and joiners, direction marks and overrides, the byte-order mark, invisible
/// operators) and the line and paragraph separators.
fn is_invisible(c: char) -> bool {
    matches!(c,
        '\u{ad}' | '\u{600}'..='\u{605}' | '\u{61c}' | '\u{6dd}' | '\u{70f}' | '\u{180e}'
        | '\u{200b}'..='\u{200f}' | '\u{2028}'..='\u{202e}' | '\u{2060}'..='\u{2064}'
        | '\u{2066}'..='\u{206f}' | '\u{feff}' | '\u{fff9}'..='\u{fffb}'
        | '\u{e0001}' | '\u{e0020}'..='\u{e007f}')
}

/// At most 40 characters of user text for an error message: a value, a key or a tag's name
/// (a line of a binary file read as a key would otherwise be echoed whole).
pub(crate) fn shorten(s: &str) -> String {
    if s.chars().count() <= 40 {
        s.to_string()
    } else {
        let mut out: String = s.chars().take(37).collect();
        out.push_str("...");
        out
    }
}

/// The diagnostics of one pass, as they are found, in bounded memory: a file of millions of
/// bad lines must not keep every one of them (160 bytes each) to print the first hundred. Only the
/// earliest [`MAX_DIAGNOSTICS`] + 1 by position are kept (the one past the shown ones says
/// where the rest begin); the others are only counted, so a diagnostic repeated word for
/// word at the same place counts twice in "more errors" if both copies are past the kept
/// ones (kept ones are deduplicated).
#[derive(Debug, Default)]
pub(crate) struct Found {
    kept: Vec<Diagnostic>,
    /// Diagnostics pushed and then dropped as later than the kept ones.
    dropped: usize,
    /// Every diagnostic pushed so far: a check compares it before and after a block to learn
    /// whether the block had errors of its own.
    pushed: usize,
}

impl Found {
    const KEEP: usize = MAX_DIAGNOSTICS + 1;

    pub(crate) fn push(&mut self, d: Diagnostic) {
        self.pushed += 1;
        self.kept.push(d);
        if self.kept.len() >= 4 * Self::KEEP {
            // Sorting is stable, so equal positions keep the order they were found in,
            // as the final sort in `SceneError::new` would have left them.
            self.kept.sort_by_key(|d| d.pos);
            self.kept.dedup();
            if self.kept.len() > Self::KEEP {
                self.dropped += self.kept.len() - Self::KEEP;
                self.kept.truncate(Self::KEEP);
            }
        }
    }

    /// The diagnostics kept so far, in no particular order.
    #[cfg(test)]
    pub(crate) fn kept(&self) -> &[Diagnostic] {
        &self.kept
    }

    pub(crate) fn pushed(&self) -> usize {
        self.pushed
    }

    /// The error these diagnostics make; `None` if there are none.
    pub(crate) fn into_error(self) -> Option<SceneError> {
        (!self.kept.is_empty()).then(|| SceneError::with_dropped(self.kept, self.dropped))
    }
}

impl fmt::Display for Diagnostic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.pos, self.message)
    }
}

/// The ways a scene can be refused: one or more positioned diagnostics, sorted by position.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub struct SceneError {
    diagnostics: Vec<Diagnostic>,
}

/// Most diagnostics one error reports; past them, one more says how many were left out. A
/// file of a million bad lines would otherwise print a million lines (and the service answer
/// them all in one JSON body); the first hundred say what is wrong as well.
pub const MAX_DIAGNOSTICS: usize = 100;

impl SceneError {
    /// Builds an error from a non-empty list; the list is sorted by position, deduplicated,
    /// and cut to the first [`MAX_DIAGNOSTICS`] plus a note of how many more there were.
    pub fn new(diagnostics: Vec<Diagnostic>) -> Self {
        Self::with_dropped(diagnostics, 0)
    }

    /// As [`new`](Self::new), with `dropped` more diagnostics found after all of these.
    fn with_dropped(mut diagnostics: Vec<Diagnostic>, dropped: usize) -> Self {
        diagnostics.sort_by_key(|d| d.pos);
        diagnostics.dedup();
        debug_assert!(!diagnostics.is_empty());
        if diagnostics.len() > MAX_DIAGNOSTICS {
            let more = diagnostics.len() - MAX_DIAGNOSTICS + dropped;
            let at = diagnostics[MAX_DIAGNOSTICS].pos;
            diagnostics.truncate(MAX_DIAGNOSTICS);
            diagnostics.push(Diagnostic::new(
                at,
                format!("{more} more errors from here on are not shown"),
            ));
        }
        SceneError { diagnostics }
    }

    /// An error of one diagnostic.
    pub fn single(pos: Pos, message: impl Into<String>) -> Self {
        SceneError::new(vec![Diagnostic::new(pos, message)])
    }

    /// The diagnostics, sorted by position (the last may count the ones left out).
    pub fn diagnostics(&self) -> &[Diagnostic] {
        &self.diagnostics
    }

    /// The first (earliest) diagnostic.
    pub fn first(&self) -> &Diagnostic {
        // `new` is the only constructor and every caller passes at least one diagnostic.
        &self.diagnostics[0]
    }

    /// Formats every diagnostic as `file:line:col: message`, one per line.
    pub fn with_file<'a>(&'a self, file: &'a str) -> WithFile<'a> {
        WithFile { error: self, file }
    }
}

/// A scene file's bytes as text. Scenes are UTF-8 (ASCII being the usual case); anything
/// else is refused at the first byte that is not, with its line and column, instead of
/// being read with replacement characters that would surface as confusing errors later.
pub fn scene_text(bytes: Vec<u8>) -> Result<String, SceneError> {
    String::from_utf8(bytes).map_err(|e| {
        let bytes = e.as_bytes();
        // `valid_up_to` is at most the length, and everything before it is valid UTF-8, so
        // its lines and characters can be counted.
        let (before, after) = bytes.split_at(e.utf8_error().valid_up_to().min(bytes.len()));
        let before = std::str::from_utf8(before).unwrap_or_default();
        let line = before.matches('\n').count() + 1;
        let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
        let pos = Pos::new(
            u32::try_from(line).unwrap_or(u32::MAX),
            u32::try_from(column).unwrap_or(u32::MAX),
        );
        SceneError::single(
            pos,
            format!(
                "not UTF-8 text (byte 0x{:02x}): a scene is a plain text file",
                after.first().copied().unwrap_or_default()
            ),
        )
    })
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, d) in self.diagnostics.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{d}")?;
        }
        Ok(())
    }
}

/// Display adapter produced by [`SceneError::with_file`].
pub struct WithFile<'a> {
    error: &'a SceneError,
    file: &'a str,
}

impl fmt::Display for WithFile<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, d) in self.error.diagnostics.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{}:{}", self.file, d)?;
        }
        Ok(())
    }
}

/// The known word closest to `word`, if it is close enough to be a plausible misspelling
/// (optimal-string-alignment distance at most one third of the longer word, and at least 1)
/// or another form of the same word (`rotation` for `rotate`: see `same_stem`).
pub fn closest<'a>(word: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let word = word.to_ascii_lowercase();
    // The nearest misspelling; failing one, the one word of the same stem (two, as `samples`
    // and `sampler` for `sample_count`, are no suggestion).
    let mut best: Option<(usize, &str)> = None;
    let mut stems: Vec<&str> = Vec::new();
    for c in candidates {
        let d = edit_distance(&word, c);
        let limit = (word.chars().count().max(c.len()) / 3).max(1);
        if d <= limit {
            if best.is_none_or(|(bd, _)| d < bd) {
                best = Some((d, c));
            }
        } else if same_stem(&word, c) {
            stems.push(c);
        }
    }
    best.map(|(_, c)| c)
        .or_else(|| (stems.len() == 1).then(|| stems[0]))
}

/// Whether `a` and `b` look like two forms of one word (`rotation` and `rotate`, `scaling`
/// and `scale`): they share a prefix of at least four characters that leaves at most the last
/// character of the shorter one out. Endings differ by more edits than a misspelling is
/// allowed, so [`edit_distance`] alone misses these.
fn same_stem(a: &str, b: &str) -> bool {
    let shorter = a.chars().count().min(b.chars().count());
    let common = a.chars().zip(b.chars()).take_while(|(x, y)| x == y).count();
    common >= 4 && common + 1 >= shorter
}

/// Optimal string alignment distance (Levenshtein plus adjacent transpositions).
fn edit_distance(a: &str, b: &str) -> usize {
    let a: Vec<char> = a.chars().collect();
    let b: Vec<char> = b.chars().collect();
    // Inputs are keys typed on one line; cap the work so a hostile 1 MB "key" costs nothing.
    if a.len() > 64 || b.len() > 64 {
        return usize::MAX;
    }
    let mut d = vec![vec![0usize; b.len() + 1]; a.len() + 1];
    for (i, row) in d.iter_mut().enumerate() {
        row[0] = i;
    }
    for (j, cell) in d[0].iter_mut().enumerate() {
        *cell = j;
    }
    for i in 1..=a.len() {
        for j in 1..=b.len() {
            let cost = usize::from(a[i - 1] != b[j - 1]);
            let mut v = (d[i - 1][j] + 1)
                .min(d[i][j - 1] + 1)
                .min(d[i - 1][j - 1] + cost);
            if i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] {
                v = v.min(d[i - 2][j - 2] + 1);
            }
            d[i][j] = v;
        }
    }
    d[a.len()][b.len()]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bounded list gives the error the whole list gives (same diagnostics shown, same
    /// count of the rest), in a few hundred entries, whatever order the positions come in.
    #[test]
    fn found_keeps_the_earliest_in_bounded_memory() {
        // Distinct positions in a scrambled order (a line twice, at different columns).
        let all: Vec<Diagnostic> = (0..20_000u32)
            .map(|i| {
                let line = (i.wrapping_mul(7_919) % 9_973) + 1;
                Diagnostic::new(Pos::new(line, 1 + i % 3), format!("e{}", line % 5))
            })
            .collect();
        let mut found = Found::default();
        let mut most = 0;
        for d in &all {
            found.push(d.clone());
            most = most.max(found.kept().len());
        }
        assert!(most < 4 * Found::KEEP, "{most}");
        assert_eq!(found.pushed(), all.len());
        let bounded = found.into_error().expect("some");
        let whole = SceneError::new(all);
        assert_eq!(bounded.diagnostics().len(), MAX_DIAGNOSTICS + 1);
        assert_eq!(
            bounded.diagnostics()[..MAX_DIAGNOSTICS],
            whole.diagnostics()[..MAX_DIAGNOSTICS]
        );
        assert_eq!(bounded, whole);
    }

    #[test]
    fn distance_counts_edits_and_transpositions() {
        assert_eq!(edit_distance("color1", "color1"), 0);
        assert_eq!(edit_distance("colr1", "color1"), 1);
        assert_eq!(edit_distance("clor1", "color1"), 1);
        assert_eq!(edit_distance("oclor1", "color1"), 1);
        assert_eq!(edit_distance("abc", "xyz"), 3);
    }

    #[test]
    fn closest_suggests_only_plausible_words() {
        let keys = ["color1", "color2", "mirror", "translate"];
        assert_eq!(closest("colour1", keys), Some("color1"));
        assert_eq!(closest("MIROR", keys), Some("mirror"));
        assert_eq!(closest("tranlsate", keys), Some("translate"));
        assert_eq!(closest("zzz", keys), None);
    }

    /// Three edits apart, more than a misspelling of a six-letter word may be, but the same
    /// word: suggested. A shared prefix that leaves more of the shorter word out is not.
    #[test]
    fn another_form_of_a_key_is_suggested() {
        let keys = ["rotate", "scale", "translate", "color1"];
        assert_eq!(closest("rotation", keys), Some("rotate"));
        assert_eq!(closest("Scaling", keys), Some("scale"));
        assert_eq!(closest("translation", keys), Some("translate"));
        assert_eq!(closest("rotor", keys), None);
        assert_eq!(closest("scarf", keys), None);
        assert_eq!(closest("transmission", keys), None);
        assert_eq!(closest("sample_count", ["sampler", "samples"]), None);
    }

    #[test]
    fn errors_are_sorted_and_formatted_with_the_file() {
        let e = SceneError::new(vec![
            Diagnostic::new(Pos::new(3, 1), "b"),
            Diagnostic::new(Pos::new(1, 9), "a"),
        ]);
        assert_eq!(
            e.with_file("s.ray").to_string(),
            "s.ray:1:9: a\ns.ray:3:1: b"
        );
        assert_eq!(e.first().message, "a");
    }

    /// The first byte that is not UTF-8, at its line and column in characters (positions
    /// worked out by hand: `ç` is one character of two bytes).
    #[test]
    fn text_that_is_not_utf8_is_refused_where_it_stops_being_utf8() {
        let at = |bytes: &[u8]| {
            let e = super::scene_text(bytes.to_vec()).expect_err("not UTF-8");
            (e.first().pos, e.first().message.clone())
        };
        let (pos, msg) = at(b"[GLOBALS]\nwidth = 8\n\xff = 1\n");
        assert_eq!(pos, Pos::new(3, 1));
        assert!(msg.contains("0xff"), "{msg}");
        assert_eq!(at(b"ab\n\xc3\xa7d\xfe").0, Pos::new(2, 3));
        // A sequence cut short by the end of the file.
        assert_eq!(at(b"abc\xe2\x82").0, Pos::new(1, 4));
        let ok = "width = 8 # caf\u{e9}\n";
        assert_eq!(super::scene_text(ok.as_bytes().to_vec()).as_deref(), Ok(ok));
    }
}
