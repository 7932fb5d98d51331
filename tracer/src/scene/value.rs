//! One entry's value read as what its key needs: numbers (finite, within [`MAX_NUMBER`]),
//! vectors, colours, names and sizes, with the error at the value's own position.

use glam::DVec3;

use crate::diag::{Diagnostic, Pos, closest, shorten};
use crate::math::Color;
use crate::transform::TransformOp;

use super::blocks::Entry;

/// A value to interpret, with its position for error messages.
pub(super) struct Value<'a> {
    pub(super) text: &'a str,
    pub(super) pos: Pos,
    pub(super) key: &'a str,
}

impl<'a> Value<'a> {
    pub(super) fn new(e: &'a Entry) -> Self {
        Value {
            text: e.value.as_str(),
            pos: e.value_pos,
            key: e.key.as_str(),
        }
    }

    pub(super) fn fail<T>(&self, expected: &str) -> Result<T, Diagnostic> {
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

    pub(super) fn at(&self, offset_chars: usize, message: String) -> Diagnostic {
        let col = self
            .pos
            .column
            .saturating_add(u32::try_from(offset_chars).unwrap_or(0));
        Diagnostic::new(Pos::new(self.pos.line, col), message)
    }

    pub(super) fn number(&self) -> Result<f64, Diagnostic> {
        parse_f64(self.text).or_else(|e| self.fail(e.expected()))
    }

    pub(super) fn number_in(&self, lo: f64, hi: f64) -> Result<f64, Diagnostic> {
        let x = self.number()?;
        if (lo..=hi).contains(&x) {
            Ok(x)
        } else {
            self.fail(&format!("a number from {lo} to {hi}"))
        }
    }

    pub(super) fn number_open(&self, lo: f64, hi: f64) -> Result<f64, Diagnostic> {
        let x = self.number()?;
        if x > lo && x < hi {
            Ok(x)
        } else {
            self.fail(&format!("a number between {lo} and {hi}, exclusive"))
        }
    }

    pub(super) fn positive(&self) -> Result<f64, Diagnostic> {
        let x = self.number()?;
        if x > 0.0 {
            Ok(x)
        } else {
            self.fail("a number greater than 0")
        }
    }

    pub(super) fn non_negative(&self) -> Result<f64, Diagnostic> {
        let x = self.number()?;
        if x >= 0.0 {
            Ok(x)
        } else {
            self.fail("a number ≥ 0")
        }
    }

    pub(super) fn whole(&self, lo: u32, hi: u32) -> Result<u32, Diagnostic> {
        let expected = format!("a whole number from {lo} to {hi}");
        match self.text.parse::<u64>() {
            Ok(n) if n >= u64::from(lo) && n <= u64::from(hi) => Ok(n as u32),
            _ => self.fail(&expected),
        }
    }

    pub(super) fn flag(&self) -> Result<bool, Diagnostic> {
        match self.text.to_ascii_lowercase().as_str() {
            "on" | "yes" | "true" => Ok(true),
            "off" | "no" | "false" => Ok(false),
            _ => self.fail("on, off, yes, no, true or false"),
        }
    }

    pub(super) fn keyword(
        &self,
        options: &[&'static str],
        what: &str,
    ) -> Result<&'static str, Diagnostic> {
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

    pub(super) fn name(&self) -> Result<String, Diagnostic> {
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
    pub(super) fn vector(&self) -> Result<DVec3, Diagnostic> {
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
    pub(super) fn color(&self) -> Result<Color, Diagnostic> {
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

    pub(super) fn transform_op(&self, key: &str) -> Result<TransformOp, Diagnostic> {
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
/// over every light. Without it, a light at 1e154 squares its distance to infinity and
/// lights nothing; colours of 1e308 sum to infinity, and `0·∞ = NaN` comes out as a white
/// pixel; an eye at 1e160 is reported as "`up` parallel to the view".
pub const MAX_NUMBER: f64 = 1e15;

/// Why a value is not a scene number.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum BadNumber {
    NotANumber,
    TooLarge,
}

impl BadNumber {
    /// What was expected, for a message.
    pub(super) fn expected(self) -> &'static str {
        match self {
            BadNumber::NotANumber => "a number like 1.5 or -2e3",
            BadNumber::TooLarge => "a number of magnitude at most 1e15",
        }
    }
}

/// A finite decimal number of magnitude at most [`MAX_NUMBER`]. Rust's parser also takes
/// `inf`, `NaN` and `infinity`; the format does not.
pub(super) fn parse_f64(s: &str) -> Result<f64, BadNumber> {
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
pub(super) struct GivenSize {
    pub(super) width: bool,
    pub(super) height: bool,
    pub(super) refused: bool,
}
