//! The user's vocabulary for decoding a map: the PCA (`--pca`, the robot's 384 → 64 projection) and the
//! class phrases (`--classes`, `--query`), read and checked against the feature space the robots declared.
//! Apart from the commands ([`super`]) because a wrong vocabulary must be refused with one clear line
//! before any map is decoded with it.

use super::OutputArgs;
use crate::base_station::{GlobalMap, VOCAB_CAP};
use crate::npy_io::NpzReader;
use crate::sim::vocab::{D, FULL_DIM};
use anyhow::{bail, Result};
use latentbki::wire::feature_space_id;
use latentbki::{decode::Codebook, decode::Pca};
use std::path::Path;

/// The vocabulary (`--pca`, `--classes`) and the query (`--query`) codebooks.
pub type Vocab = (Vec<String>, Codebook<D, VOCAB_CAP>, Box<Pca<D, FULL_DIM>>);

pub(super) fn read_vocabulary(
    args: &OutputArgs,
) -> Result<(Option<Vocab>, Option<Codebook<D, VOCAB_CAP>>)> {
    let Some(p) = &args.pca else {
        if args.classes.is_some() {
            bail!("--classes needs --pca (the PCA the robots used)");
        }
        if args.query.is_some() {
            bail!("--query needs --pca (the PCA the robots used)");
        }
        return Ok((None, None));
    };
    let pca = read_pca(p)?;
    let table = read_table(p)?;
    let names: Vec<String> = match &args.classes {
        Some(c) => c.split(',').map(|s| s.trim().to_string()).collect(),
        None => table.phrases().into_iter().take(12).collect(),
    };
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let emb = table
        .embeddings(&refs)
        .map_err(|e| anyhow::anyhow!("--classes: {e}"))?;
    let cb = Codebook::from_pca(&pca, &emb).map_err(|e| anyhow::anyhow!("vocabulary: {e}"))?;
    let query = match &args.query {
        Some(q) => {
            let e = table
                .embeddings(&[q.as_str()])
                .map_err(|e| anyhow::anyhow!("--query: {e}"))?;
            Some(
                Codebook::<D, VOCAB_CAP>::from_pca(&pca, &e)
                    .map_err(|e| anyhow::anyhow!("query: {e}"))?,
            )
        }
        None => None,
    };
    Ok((Some((names, cb, pca)), query))
}

/// The phrases words are looked up in: the committed table, plus the classes of a feature space written by
/// `host-sim feature-space` (its `vocabulary.tsv`, beside the `--pca` file), which may be words the
/// committed table lacks.
fn read_table(pca: &Path) -> Result<crate::sim::vocab::TextEmbeddings> {
    let mut table = crate::sim::vocab::TextEmbeddings::builtin();
    let beside = pca.with_file_name("vocabulary.tsv");
    if beside.is_file() {
        let text = std::fs::read_to_string(&beside)?;
        let extra = crate::sim::vocab::TextEmbeddings::parse(&text)
            .map_err(|e| anyhow::anyhow!("{}: {e}", beside.display()))?;
        table.extend(extra);
    }
    Ok(table)
}

/// The PCA must be the robots' (the map's feature-space id) or the labels would be meaningless.
pub(super) fn check_feature_space(
    args: &OutputArgs,
    vocab: Option<&Vocab>,
    map: &GlobalMap<D>,
) -> Result<()> {
    if let (Some(p), Some((_, _, pca))) = (&args.pca, vocab) {
        let id = feature_space_id(pca);
        if id != map.config().feature_space {
            bail!(
                "{}: feature-space id {id:#010x} is not the robots' ({:#010x}): labels would be meaningless",
                p.display(),
                map.config().feature_space
            );
        }
    }
    Ok(())
}

/// The `--pca` file, as [`crate::npy_io::write_pca_npz`] writes it (and numpy's `savez`).
fn read_pca(path: &Path) -> Result<Box<Pca<D, FULL_DIM>>> {
    let mut npz = NpzReader::open(path)?;
    let mut array = |name: &str, len: usize| -> Result<Vec<f32>> {
        let (_, v) = npz.array::<f32>(name)?;
        if v.len() != len {
            bail!(
                "{}: `{name}` has {} values, expected {len}",
                path.display(),
                v.len()
            );
        }
        Ok(v)
    };
    let mean = array("mean", FULL_DIM)?;
    let comps = array("components", D * FULL_DIM)?;
    let mut pca = Box::new(Pca {
        mean: [0.0; FULL_DIM],
        components: [[0.0; FULL_DIM]; D],
    });
    pca.mean.copy_from_slice(&mean);
    for (row, chunk) in pca.components.iter_mut().zip(comps.chunks_exact(FULL_DIM)) {
        row.copy_from_slice(chunk);
    }
    Ok(pca)
}
