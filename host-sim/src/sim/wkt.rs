//! A WKT reader: just enough of WKT 1 and WKT 2 to find a CRS's kind and its length units.
//!
//! A LAS file's CRS record is WKT text (LAS 1.4's record 2112, or the CRS of an EPSG code looked up in
//! `crs-definitions`). We need three facts from it — projected, geographic or geocentric; the unit of the
//! horizontal axes; the unit of the vertical axis — and no crate on crates.io reads WKT 2 without pulling
//! in PROJ, so the tree is parsed here: `KEYWORD[arg, …]` nodes with quoted strings, numbers and children.

/// A node of a WKT: `KEYWORD[arg, …]`.
#[derive(Debug)]
pub struct WktNode {
    /// The keyword, upper-cased.
    pub key: String,
    /// Its numeric arguments, in order.
    pub numbers: Vec<f64>,
    /// Its quoted arguments, in order.
    pub strings: Vec<String>,
    /// Its child nodes (and bare words), in order.
    pub children: Vec<WktNode>,
}

/// Deepest nesting accepted (real CRSs nest 5–7 deep): bounds the recursion on hostile text.
const MAX_DEPTH: usize = 32;

/// Parse WKT (1 or 2) into its node tree; `None` if it is not well formed.
pub fn parse(text: &str) -> Option<WktNode> {
    fn skip(s: &[u8], i: &mut usize) {
        while *i < s.len() && s[*i].is_ascii_whitespace() {
            *i += 1;
        }
    }
    fn node(s: &[u8], i: &mut usize, depth: usize) -> Option<WktNode> {
        if depth > MAX_DEPTH {
            return None;
        }
        skip(s, i);
        let start = *i;
        while *i < s.len() && (s[*i].is_ascii_alphanumeric() || s[*i] == b'_') {
            *i += 1;
        }
        if *i == start {
            return None; // neither a keyword nor a value: not WKT
        }
        let key = String::from_utf8_lossy(&s[start..*i]).to_uppercase();
        let mut n = WktNode {
            key,
            numbers: Vec::new(),
            strings: Vec::new(),
            children: Vec::new(),
        };
        skip(s, i);
        if *i >= s.len() || !(s[*i] == b'[' || s[*i] == b'(') {
            return Some(n); // a bare word (WKT2 axis directions, …)
        }
        *i += 1;
        loop {
            skip(s, i);
            match s.get(*i)? {
                b']' | b')' => {
                    *i += 1;
                    return Some(n);
                }
                b',' => *i += 1,
                b'"' => {
                    *i += 1;
                    let mut v = Vec::new();
                    loop {
                        match s.get(*i)? {
                            b'"' if s.get(*i + 1) == Some(&b'"') => {
                                v.push(b'"');
                                *i += 2;
                            }
                            b'"' => {
                                *i += 1;
                                break;
                            }
                            &c => {
                                v.push(c);
                                *i += 1;
                            }
                        }
                    }
                    n.strings.push(String::from_utf8_lossy(&v).into_owned());
                }
                c if c.is_ascii_digit() || *c == b'-' || *c == b'+' || *c == b'.' => {
                    let start = *i;
                    while *i < s.len() && !matches!(s[*i], b',' | b']' | b')') {
                        *i += 1;
                    }
                    let t = String::from_utf8_lossy(&s[start..*i]);
                    n.numbers.push(t.trim().parse().ok()?);
                }
                _ => n.children.push(node(s, i, depth + 1)?),
            }
        }
    }
    let mut i = 0;
    node(text.as_bytes(), &mut i, 0)
}

impl WktNode {
    /// The first node (depth first, this one included) whose keyword is one of `keys`.
    pub fn find(&self, keys: &[&str]) -> Option<&WktNode> {
        if keys.contains(&self.key.as_str()) {
            return Some(self);
        }
        self.children.iter().find_map(|c| c.find(keys))
    }
    /// The EPSG code of this node (`AUTHORITY["EPSG","32632"]` in WKT 1, `ID["EPSG",32632]` in WKT 2).
    pub fn epsg(&self) -> Option<u32> {
        let id = self
            .children
            .iter()
            .find(|c| c.key == "AUTHORITY" || c.key == "ID")?;
        if !id.strings.first()?.eq_ignore_ascii_case("EPSG") {
            return None;
        }
        match (id.strings.get(1), id.numbers.first()) {
            (Some(code), _) => code.trim().parse().ok(),
            (None, Some(&code)) if code >= 0.0 && code.fract() == 0.0 => Some(code as u32),
            _ => None,
        }
    }
    /// The length unit of a CRS node: its own `UNIT`/`LENGTHUNIT`, else its axes' (WKT2).
    pub fn length_unit(&self) -> Option<&WktNode> {
        fn own(n: &WktNode) -> Option<&WktNode> {
            n.children
                .iter()
                .find(|c| c.key == "UNIT" || c.key == "LENGTHUNIT")
        }
        own(self).or_else(|| {
            self.children
                .iter()
                .filter(|c| c.key == "AXIS" || c.key == "CS")
                .find_map(own)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_nodes_ids_and_refuses_what_is_not_wkt() {
        let n = parse(
            r#"PROJCS["x",UNIT["metre",1,AUTHORITY["EPSG","9001"]],AUTHORITY["EPSG","32632"]]"#,
        )
        .unwrap();
        assert_eq!(n.epsg(), Some(32632));
        assert_eq!(n.length_unit().unwrap().numbers, [1.0]);
        let n = parse(r#"PROJCRS["y",CS[Cartesian,2],AXIS["e",east,LENGTHUNIT["foot",0.3048]],ID["EPSG",2994]]"#).unwrap();
        assert_eq!(n.epsg(), Some(2994));
        assert_eq!(n.length_unit().unwrap().numbers, [0.3048]);
        // Not WKT, unbalanced, or nested beyond reason: `None`, never a hang or a stack overflow.
        for bad in ["=", "PROJCS[\"x\",=]", "PROJCS[\"x\"", "PROJCS[\"x", ""] {
            assert!(parse(bad).is_none(), "{bad}");
        }
        let deep = "A[".repeat(100_000) + &"]".repeat(100_000);
        assert!(parse(&deep).is_none());
    }
}
