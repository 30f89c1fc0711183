//! Real text embeddings on demand (cargo feature `encoder`): the MiniLM encoder bundled by `pocket-encoder`.
//!
//! Why a feature: the model takes ~10 minutes to build from clean, and the simulator only needs the few
//! phrases it uses, which are committed as `data/text-embeddings.tsv`. This module is the project tool that
//! (re)generates that table (`host-sim embed-vocab`) and lets `query` accept any text.

use crate::sim::vocab::FULL_DIM;
use anyhow::{bail, Context, Result};
use std::io::Write;
use std::path::Path;

/// Embed phrases: 384-d, L2-normalised.
pub fn embed(phrases: &[&str]) -> Result<Vec<[f32; FULL_DIM]>> {
    let encoder = pocket_encoder::Encoder::new()
        .map_err(|e| anyhow::anyhow!("loading the text encoder: {e:?}"))?;
    let vectors = encoder
        .embed(phrases)
        .map_err(|e| anyhow::anyhow!("embedding {phrases:?}: {e:?}"))?;
    vectors
        .into_iter()
        .zip(phrases)
        .map(|(v, p)| match <[f32; FULL_DIM]>::try_from(v) {
            Ok(a) => Ok(a),
            Err(v) => bail!(
                "\"{p}\": the encoder returned {} values, expected {FULL_DIM}",
                v.len()
            ),
        })
        .collect()
}

/// Write the table format `sim::vocab` reads: a `#` header naming the model, then `phrase<TAB>values`.
pub fn write_table(path: &Path, phrases: &[&str]) -> Result<()> {
    let vectors = embed(phrases)?;
    let info = pocket_encoder::model_info();
    let mut f = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
    );
    writeln!(
        f,
        "# model: pocket-encoder 0.1.2, id={} revision={} upstream={}@{} dims={} pooling=\"{}\"; vectors are \
         L2-normalised; format: phrase<TAB>space-separated f32 (shortest round-trip repr); written by \
         `host-sim embed-vocab`",
        info.id, info.revision, info.upstream_model, info.upstream_revision, info.dimensions, info.pooling
    )?;
    for (p, v) in phrases.iter().zip(&vectors) {
        let values: Vec<String> = v.iter().map(|x| format!("{x:?}")).collect();
        writeln!(f, "{p}\t{}", values.join(" "))?;
    }
    f.flush()?;
    Ok(())
}
