//! The simulated vision-language encoder: real text embeddings, corrupted the way segmentation networks err.
//!
//! A class's clean feature is the real 384-d text embedding of its name (an LSeg-style network is trained to
//! put a pixel's feature near its class's text embedding). Real networks do not err point by point at
//! random: they mislabel **whole segments** (a region of an object, in one view) as a **semantically close
//! class**, and the same view tends to be misread for several frames in a row. The noise model, chosen once
//! from that behaviour and not tuned to any result, is:
//!
//! 1. **Segments**: an object instance cut into 1.5 m cells (a segment is one object part seen at once).
//! 2. **Confusion**: in each block of [`NoiseModel::persistence_frames`] consecutive frames (phase-shifted
//!    per segment), a segment is confused with probability [`NoiseModel::confusion_probability`] = 0.25 (a
//!    network with about 75 % of segments right per frame — between the paper's indoor and outdoor networks).
//!    The wrong class is drawn with probability ∝ exp(cos(F_c, F_c′) / τ), τ = 0.1: similar names are
//!    confused far more often than unrelated ones.
//! 3. **Per-point noise**: isotropic Gaussian noise in the 384-d space whose expected norm equals the clean
//!    embedding's (1), since dense pixel features sit far from the text embeddings they are decoded against.
//!
//! Decisions 1–2 are hashes of (seed, segment, block), so they are reproducible and independent of point
//! order. Because projection is linear, the compressed path ([`Encoder::encode_compressed`]) adds the noise
//! after PCA: W(F + n − m) = W(F − m) + Wn with Wn ~ N(0, σ²I₆₄) exactly (orthonormal rows), which is the
//! same distribution as compressing the 384-d noisy feature, six times cheaper.

use super::vocab::{cosine, FULL_DIM};
use super::{mix_all, unit, LabelledPoint};
use latentbki::decode::Pca;
use rand::Rng;
use rand_distr::{Distribution, StandardNormal};

/// Parameters of the error model (see the module documentation for why these values).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseModel {
    /// Probability that a segment is given a wrong class in a block of frames.
    pub confusion_probability: f32,
    /// Temperature τ of the confusion distribution over classes (cosine of text embeddings / τ).
    pub confusion_temperature: f32,
    /// Frames a confusion decision lasts.
    pub persistence_frames: u32,
    /// Edge of the cells that cut instances into segments, metres.
    pub segment_cell_m: f32,
    /// Expected norm of the per-point feature noise (the clean embedding has norm 1).
    pub feature_noise: f32,
}

impl Default for NoiseModel {
    fn default() -> Self {
        Self {
            confusion_probability: 0.25,
            confusion_temperature: 0.1,
            persistence_frames: 3,
            segment_cell_m: 1.5,
            feature_noise: 1.0,
        }
    }
}

/// Turns labelled points into features.
#[derive(Clone, Debug)]
pub struct Encoder {
    embeddings: Vec<[f32; FULL_DIM]>,
    /// Per class, the cumulative distribution of the class it is confused with.
    confusion_cdf: Vec<Vec<f32>>,
    model: NoiseModel,
    seed: u64,
}

impl Encoder {
    /// An encoder for classes with these text embeddings.
    pub fn new(embeddings: Vec<[f32; FULL_DIM]>, model: NoiseModel, seed: u64) -> Self {
        let k = embeddings.len();
        let confusion_cdf = (0..k)
            .map(|c| {
                let w: Vec<f32> = (0..k)
                    .map(|o| {
                        if o == c {
                            0.0
                        } else {
                            let s = cosine(&embeddings[c], &embeddings[o]);
                            ((s - 1.0) / model.confusion_temperature).exp()
                        }
                    })
                    .collect();
                let total: f32 = w.iter().sum();
                let mut acc = 0.0;
                w.iter()
                    .map(|x| {
                        acc += x / total.max(f32::MIN_POSITIVE);
                        acc
                    })
                    .collect()
            })
            .collect();
        Self {
            embeddings,
            confusion_cdf,
            model,
            seed,
        }
    }

    /// The noise model.
    pub fn model(&self) -> &NoiseModel {
        &self.model
    }

    /// Number of classes.
    pub fn classes(&self) -> usize {
        self.embeddings.len()
    }

    /// The clean embedding of a class.
    pub fn embedding(&self, class: u16) -> &[f32; FULL_DIM] {
        &self.embeddings[usize::from(class)]
    }

    /// The segment a point belongs to: its instance and the cell it falls in.
    pub fn segment(&self, p: &LabelledPoint) -> u64 {
        let c = self.model.segment_cell_m;
        let cell = p.position.map(|x| (x / c).floor() as i64 as u64);
        mix_all(&[u64::from(p.instance), cell[0], cell[1], cell[2]])
    }

    /// The class the network reports for a point in frame `frame` (its true class unless its segment is
    /// confused in that frame's block).
    pub fn perceived_class(&self, p: &LabelledPoint, frame: u32) -> u16 {
        let seg = self.segment(p);
        let persist = self.model.persistence_frames.max(1);
        let phase = (mix_all(&[self.seed, seg, 1]) % u64::from(persist)) as u32;
        let block = u64::from((frame + phase) / persist);
        let h = mix_all(&[self.seed, seg, block, 2]);
        if unit(h) >= self.model.confusion_probability || self.embeddings.len() < 2 {
            return p.class;
        }
        let r = unit(mix_all(&[self.seed, seg, block, 3]));
        let cdf = &self.confusion_cdf[usize::from(p.class)];
        cdf.iter().position(|&x| r < x).unwrap_or(cdf.len() - 1) as u16
    }

    fn sigma(&self) -> f32 {
        self.model.feature_noise / (FULL_DIM as f32).sqrt()
    }

    /// Full 384-d features of a frame's points (used to fit the PCA).
    pub fn encode_full<R: Rng>(
        &self,
        points: &[LabelledPoint],
        frame: u32,
        rng: &mut R,
    ) -> Vec<[f32; FULL_DIM]> {
        let s = self.sigma();
        points
            .iter()
            .map(|p| {
                let mut y = *self.embedding(self.perceived_class(p, frame));
                for v in &mut y {
                    let z: f32 = StandardNormal.sample(rng);
                    *v += s * z;
                }
                y
            })
            .collect()
    }

    /// Compressed features of a frame's points: exactly distributed as `pca.project(encode_full(..))`.
    pub fn encode_compressed<const D: usize, R: Rng>(
        &self,
        points: &[LabelledPoint],
        frame: u32,
        projected: &[[f32; D]],
        rng: &mut R,
    ) -> Vec<[f32; D]> {
        let s = self.sigma();
        points
            .iter()
            .map(|p| {
                let mut y = projected[usize::from(self.perceived_class(p, frame))];
                for v in &mut y {
                    let z: f32 = StandardNormal.sample(rng);
                    *v += s * z;
                }
                y
            })
            .collect()
    }

    /// The clean class embeddings projected by `pca` (the input of [`Self::encode_compressed`]).
    pub fn project_classes<const D: usize>(&self, pca: &Pca<D, FULL_DIM>) -> Vec<[f32; D]> {
        self.embeddings.iter().map(|e| pca.project(e)).collect()
    }
}
