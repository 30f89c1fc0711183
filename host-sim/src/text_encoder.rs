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
    let worst = vectors
        .iter()
        .map(|v| (v.iter().map(|x| x * x).sum::<f32>().sqrt() - 1.0).abs())
        .fold(0.0f32, f32::max);
    let mut f = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
    );
    writeln!(
        f,
        "# model: pocket-encoder 0.1.2, id={} revision={} upstream={}@{} tokenizer_sha256={} dims={} \
         max_tokens={} pooling=\"{}\"; vectors are L2-normalised (unit norm, max |norm-1|={worst:.1e}); \
         format: phrase<TAB>space-separated f32 (shortest round-trip repr); generated {}",
        info.id,
        info.revision,
        info.upstream_model,
        info.upstream_revision,
        info.tokenizer_sha256,
        info.dimensions,
        info.max_tokens,
        info.pooling,
        today(),
    )?;
    for (p, v) in phrases.iter().zip(&vectors) {
        let values: Vec<String> = v.iter().map(|x| format!("{x:?}")).collect();
        writeln!(f, "{p}\t{}", values.join(" "))?;
    }
    f.flush()?;
    Ok(())
}

/// Today's date (UTC) as YYYY-MM-DD, from the system clock (civil-from-days, proleptic Gregorian).
fn today() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let z = (secs / 86_400) as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("{year:04}-{month:02}-{day:02}")
}
