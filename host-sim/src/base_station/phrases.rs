//! What decodes the map a viewer shows: the class names with their codebook, and the phrases a viewer
//! types, embedded (the built-in text table; with the `encoder` feature, any text) and projected with the
//! robots' PCA. Below the commands because the demo's radio hands the same vocabulary to its viewer.

use super::view::{PhraseEncoder, Viewer, Vocabulary};
use super::VOCAB_CAP;
use crate::sim::vocab::{D, FULL_DIM as FULL};
use latentbki::decode::{Codebook, Pca};

/// The base station's view.
pub type StationViewer = Viewer<D, VOCAB_CAP>;

/// One phrase's embedding: the built-in table's, else (with the `encoder` feature) the text encoder's.
fn embed(phrase: &str) -> Result<[f32; FULL], String> {
    let table = crate::sim::vocab::TextEmbeddings::builtin();
    match table.get(phrase) {
        Ok(e) => Ok(*e),
        #[cfg(feature = "encoder")]
        Err(_) => crate::text_encoder::embed(&[phrase])
            .map(|v| v[0])
            .map_err(|e| format!("\"{phrase}\": {e:#}")),
        #[cfg(not(feature = "encoder"))]
        Err(e) => Err(format!(
            "\"{phrase}\": {e} (a build with `--features encoder` encodes any text)"
        )),
    }
}

/// Phrases typed in the viewer, encoded and projected with the robots' PCA.
pub fn phrase_encoder(pca: Box<Pca<D, FULL>>) -> PhraseEncoder<D, VOCAB_CAP> {
    Box::new(move |p: &str| {
        let e = embed(p)?;
        Codebook::from_pca(&pca, &[e]).map_err(|e| format!("\"{p}\": {e}"))
    })
}

/// What decodes a map: class names, their codebook, and the phrases through the robots' PCA.
pub fn vocabulary(
    names: Vec<String>,
    codebook: Codebook<D, VOCAB_CAP>,
    pca: Box<Pca<D, FULL>>,
) -> Vocabulary<D, VOCAB_CAP> {
    Vocabulary {
        names,
        codebook,
        feature_space: Some(latentbki::wire::feature_space_id(&*pca)),
        phrases: Some(phrase_encoder(pca)),
    }
}
