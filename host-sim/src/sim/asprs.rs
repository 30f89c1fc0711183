//! The ASPRS standard classes by name (LAS 1.4 R15, table 17): what a tile's class codes are called, so
//! the simulated network and the text queries can use the committed text embeddings of those names.

/// The phrase an ASPRS standard class code decodes to (LAS 1.4 R15, table 17); `None` for reserved
/// (23–63) and user-definable (64–255) codes. Codes 0 and 1 share "unclassified", so a tile with both has
/// one such class. Where the vocabulary already had a phrase for a class (`noise`, `road` …) it is kept.
pub fn asprs_phrase(code: u8) -> Option<&'static str> {
    Some(match code {
        0 | 1 => "unclassified", // 0: created, never classified
        2 => "ground",
        3 => "low vegetation",
        4 => "medium vegetation",
        5 => "high vegetation",
        6 => "building",
        7 => "noise",           // low point (noise)
        8 => "model key point", // reserved in 1.4, model key-point in 1.0–1.3
        9 => "water",
        10 => "rail",
        11 => "road surface",
        12 => "overlap",        // reserved in 1.4, overlap points in 1.0–1.3
        13 => "guard wire",     // wire – guard (shield)
        14 => "conductor wire", // wire – conductor (phase)
        15 => "transmission tower",
        16 => "insulator", // wire-structure connector (e.g. insulator)
        17 => "bridge deck",
        18 => "high noise",
        19 => "overhead structure",
        20 => "ignored ground", // e.g. breakline proximity
        21 => "snow",
        22 => "temporal exclusion",
        _ => return None,
    })
}

/// The class phrase of a code: the ASPRS name, or "class N" for reserved and user codes.
pub fn class_phrase(code: u8) -> String {
    asprs_phrase(code).map_or_else(|| format!("class {code}"), str::to_string)
}

/// Every distinct phrase of the ASPRS standard classes (the vocabulary must hold them all).
pub fn asprs_phrases() -> Vec<&'static str> {
    let mut out: Vec<&'static str> = Vec::new();
    for p in (0..=u8::MAX).filter_map(asprs_phrase) {
        if !out.contains(&p) {
            out.push(p);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_code_has_a_name() {
        assert_eq!(class_phrase(1), "unclassified");
        assert_eq!(class_phrase(0), "unclassified");
        assert_eq!(class_phrase(9), "water");
        assert_eq!(class_phrase(17), "bridge deck");
        assert_eq!(class_phrase(23), "class 23");
        assert_eq!(class_phrase(64), "class 64");
        assert_eq!(class_phrase(255), "class 255");
        assert_eq!(asprs_phrases().len(), 22);
        // The committed table embeds every one of them.
        let vocab = super::super::vocab::TextEmbeddings::builtin();
        for p in asprs_phrases() {
            vocab.get(p).unwrap();
        }
    }
}
