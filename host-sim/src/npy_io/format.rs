//! The `.npy` format itself: a magic string, a Python-literal header (parsed here, for the few shapes
//! and dtypes numpy writes) and the raw little-endian data of 4-byte elements.

use std::io::Write;

/// An element type of the arrays this module reads and writes: a 4-byte number.
pub trait Element: Copy {
    /// numpy's type code without the byte order (`f4`, `i4`).
    const CODE: &'static str;
    /// From little-endian bytes.
    fn from_le(b: [u8; 4]) -> Self;
    /// To little-endian bytes.
    fn to_le(self) -> [u8; 4];
}

impl Element for f32 {
    const CODE: &'static str = "f4";
    fn from_le(b: [u8; 4]) -> Self {
        f32::from_le_bytes(b)
    }
    fn to_le(self) -> [u8; 4] {
        self.to_le_bytes()
    }
}

impl Element for i32 {
    const CODE: &'static str = "i4";
    fn from_le(b: [u8; 4]) -> Self {
        i32::from_le_bytes(b)
    }
    fn to_le(self) -> [u8; 4] {
        self.to_le_bytes()
    }
}

/// The header of a `.npy` file.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyHeader {
    /// The dtype as written (`<f4`; a structured dtype is kept as its literal text).
    pub descr: String,
    /// Column-major data.
    pub fortran_order: bool,
    /// The array's shape (empty for a scalar).
    pub shape: Vec<u64>,
}

impl NpyHeader {
    /// The data of a C-ordered array of `T` (either byte order), checked against the shape.
    pub fn decode<T: Element>(&self, body: &[u8]) -> Result<Vec<T>, String> {
        let big_endian = match self.descr.strip_suffix(T::CODE) {
            Some("<") => false,
            Some(">") => true,
            Some("=") => cfg!(target_endian = "big"),
            _ => return Err(format!("found dtype {}", self.descr)),
        };
        if self.fortran_order {
            return Err("found a Fortran-ordered array".into());
        }
        let n = self
            .shape
            .iter()
            .try_fold(1u64, |n, &d| n.checked_mul(d))
            .and_then(|n| usize::try_from(n).ok())
            .filter(|n| n.checked_mul(4).is_some())
            .ok_or_else(|| format!("shape {:?} is too large", self.shape))?;
        if body.len() < n * 4 {
            return Err(format!(
                "truncated data: {} bytes for shape {:?}, expected {}",
                body.len(),
                self.shape,
                n * 4
            ));
        }
        if body.len() > n * 4 {
            return Err(format!(
                "{} bytes of trailing data: {} bytes for shape {:?}, expected {}",
                body.len() - n * 4,
                body.len(),
                self.shape,
                n * 4
            ));
        }
        Ok(body[..n * 4]
            .chunks_exact(4)
            .map(|c| {
                let mut b = [c[0], c[1], c[2], c[3]];
                if big_endian {
                    b.reverse();
                }
                T::from_le(b)
            })
            .collect())
    }
}

/// Split a `.npy` file into its header and data (versions 1, 2 and 3 of the format).
pub fn parse_npy(bytes: &[u8]) -> Result<(NpyHeader, &[u8]), String> {
    let rest = bytes
        .strip_prefix(b"\x93NUMPY")
        .ok_or("no .npy magic string")?;
    let version = *rest.first().ok_or("no format version")?;
    let (width, start): (usize, usize) = match version {
        1 => (2, 10),
        2 | 3 => (4, 12),
        v => return Err(format!("unknown format version {v}")),
    };
    // The header length: little-endian u16 (version 1) or u32.
    let len = rest
        .get(2..2 + width)
        .ok_or("truncated header")?
        .iter()
        .rev()
        .fold(0usize, |n, &b| n << 8 | b as usize);
    let text = bytes
        .get(start..start.saturating_add(len))
        .ok_or("truncated header")?;
    let text = std::str::from_utf8(text).map_err(|_| "header is not text")?;
    let header = parse_header(text).map_err(|e| {
        // Quote the header, but not a hostile 60 kB of it.
        let text = text.trim_end();
        match text.char_indices().nth(120) {
            Some((cut, _)) => format!("header `{}…` ({} bytes): {e}", &text[..cut], text.len()),
            None => format!("header `{text}`: {e}"),
        }
    })?;
    Ok((header, &bytes[start + len..]))
}

/// A value of the Python-literal subset that `.npy` headers use.
#[derive(Debug)]
enum Lit<'a> {
    Str(&'a str),
    Int(u64),
    Bool(bool),
    Seq(Vec<Lit<'a>>),
    Dict(Vec<(Lit<'a>, Lit<'a>)>),
    None,
}

/// How deeply a header's literals may nest (numpy's headers nest 3 deep at most, for structured dtypes):
/// the parser recurses, and a hostile header of 60,000 `[` would overflow the stack.
const MAX_NESTING: usize = 16;

struct LitParser<'a> {
    s: &'a str,
    i: usize,
    /// Open brackets around the current position.
    depth: usize,
}

impl<'a> LitParser<'a> {
    fn ws(&mut self) {
        while self.s[self.i..].starts_with(|c: char| c.is_ascii_whitespace()) {
            self.i += 1;
        }
    }

    fn eat(&mut self, c: char) -> bool {
        self.ws();
        let hit = self.s[self.i..].starts_with(c);
        if hit {
            self.i += 1;
        }
        hit
    }

    /// Items up to `close`, separated by commas, a trailing comma allowed.
    fn items<T>(
        &mut self,
        close: char,
        mut item: impl FnMut(&mut Self) -> Result<T, String>,
    ) -> Result<Vec<T>, String> {
        let mut out = Vec::new();
        loop {
            if self.eat(close) {
                return Ok(out);
            }
            out.push(item(self)?);
            if self.eat(close) {
                return Ok(out);
            }
            if !self.eat(',') {
                return Err(format!("expected `,` or `{close}` at byte {}", self.i));
            }
        }
    }

    fn value(&mut self) -> Result<Lit<'a>, String> {
        self.ws();
        let rest = &self.s[self.i..];
        let Some(c) = rest.chars().next() else {
            return Err("unexpected end".into());
        };
        if matches!(c, '(' | '[' | '{') {
            if self.depth >= MAX_NESTING {
                return Err(format!(
                    "nested deeper than {MAX_NESTING} levels at byte {}",
                    self.i
                ));
            }
            self.depth += 1;
            let v = self.nested(c);
            self.depth -= 1;
            return v;
        }
        match c {
            '\'' | '"' => {
                let end = rest[1..]
                    .find(c)
                    .ok_or_else(|| format!("unterminated string at byte {}", self.i))?;
                self.i += end + 2;
                Ok(Lit::Str(&rest[1..=end]))
            }
            _ => {
                let len = rest
                    .find(|c: char| !c.is_ascii_alphanumeric())
                    .unwrap_or(rest.len());
                let word = &rest[..len];
                self.i += len;
                match word {
                    "True" => Ok(Lit::Bool(true)),
                    "False" => Ok(Lit::Bool(false)),
                    "None" => Ok(Lit::None),
                    // Python 2 wrote long integers with an `L`.
                    _ => word
                        .strip_suffix('L')
                        .unwrap_or(word)
                        .parse()
                        .map(Lit::Int)
                        .map_err(|_| format!("unexpected `{word}`")),
                }
            }
        }
    }

    /// A tuple, list or dict opening with `open` (at the current position).
    fn nested(&mut self, open: char) -> Result<Lit<'a>, String> {
        self.i += 1;
        match open {
            '{' => Ok(Lit::Dict(self.items('}', |p| {
                let k = p.value()?;
                if !p.eat(':') {
                    return Err(format!("expected `:` at byte {}", p.i));
                }
                Ok((k, p.value()?))
            })?)),
            '(' => Ok(Lit::Seq(self.items(')', Self::value)?)),
            _ => Ok(Lit::Seq(self.items(']', Self::value)?)),
        }
    }
}

fn parse_header(text: &str) -> Result<NpyHeader, String> {
    let mut p = LitParser {
        s: text,
        i: 0,
        depth: 0,
    };
    let Lit::Dict(entries) = p.value()? else {
        return Err("not a dict".into());
    };
    let (mut descr, mut fortran_order, mut shape) = (None, None, None);
    for (key, value) in entries {
        match (key, value) {
            (Lit::Str("descr"), Lit::Str(d)) => descr = Some(d.to_owned()),
            (Lit::Str("descr"), other) => descr = Some(format!("{other:?}")),
            (Lit::Str("fortran_order"), Lit::Bool(b)) => fortran_order = Some(b),
            (Lit::Str("shape"), Lit::Seq(dims)) => {
                let dims = dims.into_iter().map(|d| match d {
                    Lit::Int(d) => Ok(d),
                    other => Err(format!("bad dimension {other:?}")),
                });
                shape = Some(dims.collect::<Result<Vec<_>, _>>()?);
            }
            (key, _) => return Err(format!("unexpected entry {key:?}")),
        }
    }
    Ok(NpyHeader {
        descr: descr.ok_or("no `descr`")?,
        fortran_order: fortran_order.ok_or("no `fortran_order`")?,
        shape: shape.ok_or("no `shape`")?,
    })
}

/// Write a C-ordered little-endian array of `T` as a version 1.0 `.npy` (the header padded as numpy pads
/// it, so the data starts 64-byte aligned).
pub fn write_npy<T: Element>(
    w: &mut impl Write,
    shape: &[u64],
    data: impl IntoIterator<Item = T>,
) -> std::io::Result<()> {
    let dims: Vec<String> = shape.iter().map(u64::to_string).collect();
    let shape_text = match dims.len() {
        1 => format!("({},)", dims[0]),
        _ => format!("({})", dims.join(", ")),
    };
    let mut header = format!(
        "{{'descr': '<{}', 'fortran_order': False, 'shape': {shape_text}, }}",
        T::CODE
    );
    let total = 10 + header.len() + 1;
    header.extend(std::iter::repeat_n(' ', total.next_multiple_of(64) - total));
    header.push('\n');
    let len = u16::try_from(header.len())
        .map_err(|_| std::io::Error::other("array shape too long for a .npy header"))?;
    w.write_all(b"\x93NUMPY\x01\x00")?;
    w.write_all(&len.to_le_bytes())?;
    w.write_all(header.as_bytes())?;
    let expected: u64 = shape.iter().product();
    let mut written = 0u64;
    for x in data {
        w.write_all(&x.to_le())?;
        written += 1;
    }
    if written != expected {
        return Err(std::io::Error::other(format!(
            "{written} values for shape {shape:?}"
        )));
    }
    Ok(())
}
