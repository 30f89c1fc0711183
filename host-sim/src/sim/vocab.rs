//! The committed vocabulary: real 384-d text embeddings of class names and query words.
//!
//! `data/text-embeddings.tsv` was computed once by `pocket-encoder` (MiniLM). It is compiled into the binary
//! so that the simulator's encoder, the decoders and `query` agree on the same vectors and need no model at
//! run time. Unknown words are an error that lists what is available, never a silent fallback.

use std::fmt;

/// Dimension of the committed text embeddings.
pub const FULL_DIM: usize = 384;

/// The dimension the PCA compresses them to: every host map's, the demo robot's and the base station's
/// features (the paper's 64; the wire's D). Defined once on the host.
pub const D: usize = 64;

const TABLE: &str = include_str!("../../data/text-embeddings.tsv");

/// Phrases and their unit-length embeddings, in file order.
#[derive(Clone, Debug)]
pub struct TextEmbeddings {
    entries: Vec<(String, Box<[f32; FULL_DIM]>)>,
}

/// A word that is not in the committed vocabulary.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnknownWord {
    /// What was asked for.
    pub word: String,
    /// Every phrase that is available.
    pub available: Vec<String>,
}

impl fmt::Display for UnknownWord {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "\"{}\" is not in the committed vocabulary (host-sim/data/text-embeddings.tsv); available: {}",
            self.word,
            self.available.join(", ")
        )
    }
}

impl std::error::Error for UnknownWord {}

impl TextEmbeddings {
    /// The table compiled into the binary.
    pub fn builtin() -> Self {
        Self::parse(TABLE).expect("the committed embedding table is well formed")
    }

    /// Parse `phrase<TAB>v0 … v383` lines; `#` lines are comments.
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut entries = Vec::new();
        for (n, line) in text.lines().enumerate() {
            if line.starts_with('#') || line.trim().is_empty() {
                continue;
            }
            let (phrase, values) = line
                .split_once('\t')
                .ok_or_else(|| format!("line {}: no tab", n + 1))?;
            let mut v = Box::new([0.0f32; FULL_DIM]);
            let mut count = 0;
            for (i, tok) in values.split_whitespace().enumerate() {
                if i >= FULL_DIM {
                    return Err(format!("line {}: more than {FULL_DIM} values", n + 1));
                }
                v[i] = tok
                    .parse()
                    .map_err(|e| format!("line {}: value {i}: {e}", n + 1))?;
                count += 1;
            }
            if count != FULL_DIM {
                return Err(format!(
                    "line {}: {count} values, expected {FULL_DIM}",
                    n + 1
                ));
            }
            entries.push((phrase.to_string(), v));
        }
        Ok(Self { entries })
    }

    /// Add `other`'s phrases that this table lacks (e.g. a feature space's `vocabulary.tsv`).
    pub fn extend(&mut self, other: TextEmbeddings) {
        for (phrase, v) in other.entries {
            if !self.entries.iter().any(|(p, _)| *p == phrase) {
                self.entries.push((phrase, v));
            }
        }
    }

    /// All phrases, in file order.
    pub fn phrases(&self) -> Vec<String> {
        self.entries.iter().map(|(p, _)| p.clone()).collect()
    }

    /// The embedding of a phrase (exact match after trimming and lower-casing).
    pub fn get(&self, phrase: &str) -> Result<&[f32; FULL_DIM], UnknownWord> {
        let want = phrase.trim().to_lowercase();
        self.entries
            .iter()
            .find(|(p, _)| *p == want)
            .map(|(_, v)| &**v)
            .ok_or_else(|| UnknownWord {
                word: phrase.to_string(),
                available: self.phrases(),
            })
    }

    /// Embeddings of several phrases, in order.
    pub fn embeddings(&self, phrases: &[&str]) -> Result<Vec<[f32; FULL_DIM]>, UnknownWord> {
        phrases.iter().map(|p| self.get(p).copied()).collect()
    }

    /// The clean features of a scene's classes: the text embedding of each phrase, except that a class
    /// without a name ("class N": a reserved or user-defined ASPRS code) gets a fixed pseudo-random unit
    /// direction seeded by its phrase ([`unnamed_class_direction`]). Such a class is mapped and decoded as
    /// a class of its own; no text query can find it, since its name says nothing.
    pub fn class_embeddings(&self, phrases: &[&str]) -> Result<Vec<[f32; FULL_DIM]>, UnknownWord> {
        phrases
            .iter()
            .map(|p| match self.get(p) {
                Ok(e) => Ok(*e),
                Err(_) if is_unnamed_class(p) => Ok(unnamed_class_direction(p)),
                Err(e) => Err(e),
            })
            .collect()
    }
}

/// Whether a phrase is the placeholder name of a class without one ("class 64").
pub fn is_unnamed_class(phrase: &str) -> bool {
    phrase
        .strip_prefix("class ")
        .is_some_and(|n| n.parse::<u32>().is_ok())
}

/// The feature direction of an unnamed class: a unit vector of independent Gaussians, seeded by the
/// phrase (so every run and every tool agrees). In 384 dimensions it is nearly orthogonal to every text
/// embedding (|cos| ≈ 0.05), so the simulated network rarely confuses it with a named class.
pub fn unnamed_class_direction(phrase: &str) -> [f32; FULL_DIM] {
    use rand_distr::Distribution;
    use rand_xoshiro::rand_core::SeedableRng;
    let seed = phrase
        .bytes()
        .fold(0x000C_1A55_u64, |h, b| super::mix(h ^ u64::from(b)));
    let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut v = [0.0f32; FULL_DIM];
    for x in &mut v {
        *x = rand_distr::StandardNormal.sample(&mut rng);
    }
    let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    v.map(|x| x / norm)
}

/// Cosine similarity of two vectors (0 if either is zero).
pub fn cosine(a: &[f32], b: &[f32]) -> f32 {
    let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
    let na: f32 = a.iter().map(|x| x * x).sum::<f32>().sqrt();
    let nb: f32 = b.iter().map(|x| x * x).sum::<f32>().sqrt();
    if na > 0.0 && nb > 0.0 {
        dot / (na * nb)
    } else {
        0.0
    }
}
