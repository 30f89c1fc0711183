//! The feature space a new robot's classes live in, for both ends of the link (written by `host-sim
//! feature-space --classes floor,wall,sofa --out DIR`, [`crate::cli::feature_space`]):
//!
//! - `DIR/pca.npz` — the projection 384 → 64 (`mean`, `components`) the base station decodes with
//!   (`map-query --pca DIR/pca.npz --classes …`); its CRC-32 is the feature-space id the robot declares.
//! - `DIR/feature_space.rs` — the firmware's constants: the id, the int8 scale, and each class's int8
//!   prototype as a [`latentbki::classes::ClassPrototypes`] (`include!` it or copy it into the firmware).
//! - `DIR/vocabulary.tsv` — the classes' text embeddings, so the base station can decode classes that are
//!   not in the committed table (the base station reads it beside `--pca`).
//!
//! What the projection is fitted on matters for every query the map will ever answer: it must keep the
//! robot's classes exactly (their prototypes decode back to themselves) and keep as much as it can of the
//! other words people will ask for. So its first components span the classes (Gram–Schmidt of the
//! centred class embeddings), and the rest are the principal components of the committed vocabulary
//! (`host-sim/data/text-embeddings.tsv`, 64 phrases of indoor and outdoor classes and queries) after the
//! classes' span is taken out. Every committed phrase then lies in the space exactly (the 64 phrases span
//! at most 63 dimensions about their mean), so a query in any of them scores as in 384 dimensions; other
//! text (feature `encoder`) is projected onto that span. The int8 code convention is
//! [`latentbki::classes`]'s.

use crate::npy_io::write_pca_npz;
use crate::sim::vocab::{TextEmbeddings, FULL_DIM};
use anyhow::{bail, Context, Result};
use latentbki::classes::ClassPrototypes;
use latentbki::decode::{Codebook, Pca};
use latentbki::nalgebra::{DMatrix, SymmetricEigen};
use latentbki::wire::feature_space_id;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

pub use crate::sim::vocab::D;

/// A fitted feature space and its classes' int8 prototypes.
pub struct FeatureSpace {
    /// The classes, as given.
    pub classes: Vec<String>,
    /// Their 384-d text embeddings.
    pub embeddings: Vec<[f32; FULL_DIM]>,
    /// The projection.
    pub pca: Box<Pca<D, FULL_DIM>>,
    /// Its id ([`feature_space_id`]).
    pub id: u32,
    /// A code c stands for `scale` · c.
    pub scale: f32,
    /// Per class, its int8 prototype.
    pub codes: Vec<[i8; D]>,
}

impl FeatureSpace {
    /// Fit the space for `classes` (embeddings from the committed table, or the encoder).
    pub fn new(classes: &[String]) -> Result<Self> {
        let table = TextEmbeddings::builtin();
        if classes.is_empty() {
            bail!("--classes: no class given");
        }
        for (i, c) in classes.iter().enumerate() {
            if c.trim().is_empty() {
                bail!("--classes: class {} is empty", i + 1);
            }
            if classes[..i]
                .iter()
                .any(|p| p.trim().eq_ignore_ascii_case(c.trim()))
            {
                bail!("--classes: \"{c}\" is given twice");
            }
        }
        if classes.len() > D {
            bail!("--classes: {} classes, at most {D}", classes.len());
        }
        let embeddings = class_embeddings(&table, classes)?;
        let vocabulary: Vec<[f32; FULL_DIM]> = table
            .phrases()
            .iter()
            .map(|p| *table.get(p).expect("a phrase of the table"))
            .collect();
        let pca = fit(&embeddings, &vocabulary);
        let id = feature_space_id(&pca);
        let projected: Vec<[f32; D]> = embeddings.iter().map(|e| pca.project(e)).collect();
        let largest = projected
            .iter()
            .flatten()
            .fold(0.0f32, |m, v| m.max(v.abs()));
        if largest.is_nan() || largest <= 0.0 {
            bail!("--classes: the classes' embeddings coincide with their mean: nothing to tell apart");
        }
        let scale = largest / 127.0;
        let codes = projected
            .iter()
            .map(|p| p.map(|v| (v / scale).round().clamp(-127.0, 127.0) as i8))
            .collect();
        Ok(Self {
            classes: classes.iter().map(|c| c.trim().to_string()).collect(),
            embeddings,
            pca,
            id,
            scale,
            codes,
        })
    }

    /// How well each class's int8 prototype decodes back: per class, (cosine with its own embedding, the
    /// class it decodes to).
    pub fn round_trip(&self) -> Vec<(f32, usize)> {
        let book = Codebook::<D, 256>::from_pca(&self.pca, &self.embeddings)
            .expect("at most 64 classes, orthonormal rows");
        self.codes
            .iter()
            .enumerate()
            .map(|(k, c)| {
                let z = c.map(|v| f32::from(v) * self.scale);
                let back = self.pca.back_project(&z);
                let cos = crate::sim::vocab::cosine(&back, &self.embeddings[k]);
                (cos, book.argmax(&z).map_or(usize::MAX, |(l, _)| l))
            })
            .collect()
    }

    /// The firmware's constants as Rust source.
    pub fn rust_source(&self) -> String {
        let k = self.classes.len();
        let mut s = String::new();
        let names = self
            .classes
            .iter()
            .map(|c| format!("{c:?}"))
            .collect::<Vec<_>>()
            .join(", ");
        let _ = writeln!(
            s,
            "// Generated by `host-sim feature-space --classes {}` — regenerate, do not edit.",
            self.classes.join(",")
        );
        let _ = writeln!(
            s,
            "// The base station decodes with the pca.npz beside this file (map-query --pca …/pca.npz --classes {}).",
            self.classes.join(",")
        );
        s += "// A code c stands for INT8_SCALE · c; a class's codes are round(W (e − m) / INT8_SCALE), e its text\n";
        s += "// embedding, m and W pca.npz's mean and components (latentbki::classes).\n\n";
        let _ = writeln!(
            s,
            "/// Id of the feature space (CRC-32 of pca.npz): `Setup::with_feature_space(FEATURE_SPACE)`."
        );
        let _ = writeln!(s, "pub const FEATURE_SPACE: u32 = {:#010x};", self.id);
        let _ = writeln!(
            s,
            "/// A code c stands for INT8_SCALE · c: `Setup::with_int8_features(INT8_SCALE)`."
        );
        let _ = writeln!(s, "pub const INT8_SCALE: f32 = {:?};", self.scale);
        let _ = writeln!(
            s,
            "/// The classes, in the order of the segmenter's scores."
        );
        let _ = writeln!(s, "pub const CLASSES: [&str; {k}] = [{names}];");
        let _ = writeln!(
            s,
            "/// Each class's feature as int8 codes: `PROTOTYPES.mix(&scores, &mut codes)` per point."
        );
        let _ = writeln!(
            s,
            "pub const PROTOTYPES: latentbki::classes::ClassPrototypes<{D}, {k}> ="
        );
        let _ = writeln!(
            s,
            "    latentbki::classes::ClassPrototypes::new(FEATURE_SPACE, INT8_SCALE, ["
        );
        for (name, codes) in self.classes.iter().zip(&self.codes) {
            let _ = writeln!(s, "        // {name}");
            let all: Vec<String> = codes.iter().map(|c| c.to_string()).collect();
            let _ = writeln!(s, "        [");
            for chunk in all.chunks(16) {
                let _ = writeln!(s, "            {},", chunk.join(", "));
            }
            let _ = writeln!(s, "        ],");
        }
        let _ = writeln!(s, "    ]);");
        s
    }

    /// The classes' embeddings in the committed table's format (`phrase<TAB>384 values`).
    pub fn vocabulary_tsv(&self) -> String {
        let mut s = String::from(
            "# the classes of this feature space and their 384-d text embeddings (host-sim feature-space)\n",
        );
        for (name, e) in self.classes.iter().zip(&self.embeddings) {
            let values: Vec<String> = e.iter().map(|v| format!("{v:?}")).collect();
            let _ = writeln!(s, "{name}\t{}", values.join(" "));
        }
        s
    }

    /// Write the three files into `dir` (created if missing).
    pub fn write(&self, dir: &Path) -> Result<[PathBuf; 3]> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let npz = dir.join("pca.npz");
        write_pca_npz(&npz, &self.pca)?;
        let rs = dir.join("feature_space.rs");
        std::fs::write(&rs, self.rust_source()).with_context(|| rs.display().to_string())?;
        let tsv = dir.join("vocabulary.tsv");
        std::fs::write(&tsv, self.vocabulary_tsv()).with_context(|| tsv.display().to_string())?;
        Ok([npz, rs, tsv])
    }

    /// The prototypes as the firmware sees them.
    pub fn prototypes<const K: usize>(&self) -> Option<ClassPrototypes<D, K>> {
        let codes: [[i8; D]; K] = self.codes.clone().try_into().ok()?;
        Some(ClassPrototypes::new(self.id, self.scale, codes))
    }
}

/// The classes' embeddings: from the committed table, else (feature `encoder`) from the text encoder.
fn class_embeddings(table: &TextEmbeddings, classes: &[String]) -> Result<Vec<[f32; FULL_DIM]>> {
    let unknown: Vec<&str> = classes
        .iter()
        .map(|c| c.trim())
        .filter(|c| table.get(c).is_err())
        .collect();
    if unknown.is_empty() {
        let refs: Vec<&str> = classes.iter().map(|c| c.trim()).collect();
        return Ok(table.embeddings(&refs)?);
    }
    #[cfg(feature = "encoder")]
    {
        let refs: Vec<&str> = classes.iter().map(|c| c.trim()).collect();
        crate::text_encoder::embed(&refs)
    }
    #[cfg(not(feature = "encoder"))]
    bail!(
        "--classes: {} not in the committed vocabulary (host-sim/data/text-embeddings.tsv: {}); other words need \
         the text encoder: cargo run --release -p host-sim --features encoder -- feature-space … (~10 min cold build)",
        unknown
            .iter()
            .map(|w| format!("\"{w}\""))
            .collect::<Vec<_>>()
            .join(", ")
            + if unknown.len() == 1 { " is" } else { " are" },
        table.phrases().join(", ")
    )
}

/// The projection: the classes' span first, then the vocabulary's principal components outside it, then
/// (if the two together span fewer than `D` dimensions) coordinate directions outside both. Rows
/// orthonormal; signs deterministic. Fitted in f64.
pub fn fit(classes: &[[f32; FULL_DIM]], vocabulary: &[[f32; FULL_DIM]]) -> Box<Pca<D, FULL_DIM>> {
    let samples: Vec<&[f32; FULL_DIM]> = vocabulary.iter().chain(classes).collect();
    let n = samples.len() as f64;
    let mut mean = [0.0f64; FULL_DIM];
    for s in &samples {
        for (m, v) in mean.iter_mut().zip(s.iter()) {
            *m += f64::from(*v) / n;
        }
    }
    let centred = |e: &[f32; FULL_DIM]| -> Vec<f64> {
        e.iter()
            .zip(&mean)
            .map(|(v, m)| f64::from(*v) - m)
            .collect()
    };
    let mut rows: Vec<Vec<f64>> = Vec::with_capacity(D);
    // Take `v` as the next row if it still has length once the rows so far are taken out.
    let push_orthogonal = |rows: &mut Vec<Vec<f64>>, mut v: Vec<f64>| {
        let norm0 = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        for _ in 0..2 {
            // twice: Gram–Schmidt re-orthogonalised
            for r in rows.iter() {
                let dot: f64 = r.iter().zip(&v).map(|(a, b)| a * b).sum();
                v.iter_mut().zip(r).for_each(|(x, a)| *x -= dot * a);
            }
        }
        let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
        if rows.len() < D && norm > 1e-6 * norm0.max(1e-12) && norm > 1e-9 {
            rows.push(v.into_iter().map(|x| x / norm).collect());
        }
    };
    for c in classes {
        push_orthogonal(&mut rows, centred(c));
    }
    // The vocabulary's variance outside the classes' span.
    let k = rows.len();
    let residuals = DMatrix::<f64>::from_fn(samples.len(), FULL_DIM, |i, j| {
        let x = centred(samples[i]);
        let mut r = x[j];
        for row in &rows[..k] {
            let dot: f64 = row.iter().zip(&x).map(|(a, b)| a * b).sum();
            r -= dot * row[j];
        }
        r
    });
    let cov = residuals.tr_mul(&residuals) / n;
    let eig = SymmetricEigen::new(cov);
    let mut order: Vec<usize> = (0..FULL_DIM).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let top = eig.eigenvalues[order[0]].max(0.0);
    for &col in &order {
        if rows.len() == D || eig.eigenvalues[col] <= 1e-10 * top {
            break; // beyond the vocabulary's span: numerical noise, no direction worth keeping
        }
        let v: Vec<f64> = eig.eigenvectors.column(col).iter().copied().collect();
        // A deterministic sign: the largest-magnitude entry positive.
        let big = (0..FULL_DIM)
            .max_by(|&a, &b| v[a].abs().total_cmp(&v[b].abs()))
            .unwrap_or(0);
        let sign = if v[big] < 0.0 { -1.0 } else { 1.0 };
        push_orthogonal(&mut rows, v.into_iter().map(|x| sign * x).collect());
    }
    // Fill up with coordinate directions (deterministic), orthogonalised.
    for axis in 0..FULL_DIM {
        if rows.len() == D {
            break;
        }
        let mut v = vec![0.0; FULL_DIM];
        v[axis] = 1.0;
        push_orthogonal(&mut rows, v);
    }
    let mut pca = Box::new(Pca {
        mean: mean.map(|m| m as f32),
        components: [[0.0f32; FULL_DIM]; D],
    });
    for (dst, row) in pca.components.iter_mut().zip(&rows) {
        for (d, v) in dst.iter_mut().zip(row) {
            *d = *v as f32;
        }
    }
    pca
}
