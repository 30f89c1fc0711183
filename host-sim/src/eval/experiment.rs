//! The paper's protocol, run end to end on a simulated sequence.
//!
//! 1. Fit the PCA 384 → 64 on a *training* sequence (its own seed), build the codebook of the scene's class
//!    names from the committed text embeddings.
//! 2. Encode the *test* sequence with the simulated network; per frame, a seeded 80 % of the points are
//!    integrated and 20 % held out (§IV-A).
//! 3. Every method sees the same frames. After integrating frame t, each held-out point of frame t is
//!    predicted from the map as it is then (the voxel it falls in; never observed = unknown = wrong) and
//!    counted in the method's confusion matrix.
//! 4. For the LatentBKI f = 3 map, each held-out point also gets its voxel's E- and D-optimality (the
//!    authors' t_var and the Student-t covariance) and sampling uncertainty (the authors' procedure and the
//!    model's predictive), for the sparsification analysis.
//!
//! Methods (and the sparsity sweep's runs) run in parallel threads ([`super::runner`]: one run per thread,
//! frames in order), so results do not depend on scheduling: same seed, same table.

use super::methods::{
    CategoricalBki, Decoder, EncodedFrame, Feature, Heuristic, LatentBki, MappingMethod, OnDevice,
    Radio, RunningMean, SegmentationOnly, D,
};
use super::metrics::Confusion;
use super::sparsification::ScoredPoint;
use crate::sim::encoder::{Encoder, NoiseModel};
use crate::sim::vocab::{TextEmbeddings, FULL_DIM};
use crate::sim::{mix_all, pca, unit, Sequence};
use indicatif::ProgressBar;
use latentbki::{
    decode::Pca, inference::Spread, quant::MeanWeights, sampling::Sampler, sampling::SamplingMode,
    stats::VoxelStats, MapConfig,
};
use rand_xoshiro::rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;
use std::time::Instant;

/// Settings of an experiment that are not the scene's.
#[derive(Clone, Copy, Debug)]
pub struct ExperimentSettings {
    /// The simulated network's error model.
    pub noise: NoiseModel,
    /// Seed of the test sequence's encoder noise and hold-out split.
    pub seed: u64,
    /// Fraction of each frame held out.
    pub holdout: f32,
    /// Draws per voxel for the sampling uncertainty (the authors': 30).
    pub sampling_draws: usize,
    /// Training points used to fit the PCA.
    pub pca_samples: usize,
    /// Window radius of the device map, metres: at least the sensor range plus the kernel reach, or
    /// the device would refuse points at the edge of its view (the tile default: 10 m LiDAR).
    pub device_window: f32,
}

impl Default for ExperimentSettings {
    fn default() -> Self {
        Self {
            noise: NoiseModel::default(),
            seed: 7,
            holdout: 0.2,
            sampling_draws: latentbki::sampling::AUTHORS_DRAWS,
            pca_samples: 8000,
            device_window: 11.0,
        }
    }
}

/// The decoding side of a scene: class embeddings, PCA and codebook.
pub struct Decoding {
    /// Class phrases.
    pub classes: Vec<String>,
    /// The PCA fitted on the training sequence.
    pub pca: Box<Pca<D, FULL_DIM>>,
    /// Share of the training features' variance the PCA keeps.
    pub explained_variance: f64,
    /// The on-device map's per-dimension weights of its mean codes, from the spread of each PCA
    /// component over the training features ([`MeanWeights::from_spreads`]).
    pub mean_weights: MeanWeights,
    /// The codebook of the class phrases.
    pub decoder: Decoder,
    /// The encoder of the test sequence.
    pub encoder: Encoder,
    /// The clean class embeddings, projected.
    pub projected: Vec<Feature>,
}

/// Fit the PCA on `train` (encoded with a seed of its own) and build the codebook.
pub fn decoding(
    vocab: &TextEmbeddings,
    train: &Sequence,
    setup: &ExperimentSettings,
) -> anyhow::Result<Decoding> {
    let names: Vec<&str> = train.classes.iter().map(String::as_str).collect();
    let embeddings = vocab.class_embeddings(&names)?;
    let train_seed = mix_all(&[setup.seed, 0x7EA1]);
    let train_encoder = Encoder::new(embeddings.clone(), setup.noise, train_seed);
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(train_seed);
    let total = train.points().max(1);
    let stride = (total / setup.pca_samples.max(1)).max(1);
    let mut samples: Vec<[f32; FULL_DIM]> = Vec::with_capacity(setup.pca_samples);
    let mut n = 0usize;
    for (t, f) in train.frames.iter().enumerate() {
        let chosen: Vec<_> = f
            .points
            .iter()
            .filter(|_| {
                n += 1;
                n.is_multiple_of(stride)
            })
            .copied()
            .collect();
        samples.extend(train_encoder.encode_full(&chosen, t as u32, &mut rng));
    }
    let pca = pca::fit::<D>(&samples).map_err(|e| {
        anyhow::anyhow!("fitting the feature PCA on the training sequence: {e} (more points per frame, or more frames, are needed)")
    })?;
    let explained_variance = pca::explained_variance(&pca, &samples);
    let mean_weights = MeanWeights::from_spreads(&pca::spreads(&pca, &samples));
    let decoder = Decoder::from_pca(&pca, &embeddings)
        .map_err(|e| anyhow::anyhow!("building the codebook: {e}"))?;
    let encoder = Encoder::new(embeddings, setup.noise, setup.seed);
    let projected = encoder.project_classes(&pca);
    Ok(Decoding {
        classes: train.classes.clone(),
        pca,
        explained_variance,
        mean_weights,
        decoder,
        encoder,
        projected,
    })
}

/// Encode a sequence and split each frame into integrated and held-out points.
pub fn encode(seq: &Sequence, dec: &Decoding, setup: &ExperimentSettings) -> Vec<EncodedFrame> {
    seq.frames
        .iter()
        .enumerate()
        .map(|(t, f)| {
            let mut rng =
                Xoshiro256PlusPlus::seed_from_u64(mix_all(&[setup.seed, t as u64, 0xE1C]));
            let feats =
                dec.encoder
                    .encode_compressed(&f.points, t as u32, &dec.projected, &mut rng);
            let inv = f.pose.inverse();
            let mut out = EncodedFrame {
                pose: f.pose,
                points: Vec::new(),
                map_points: Vec::new(),
                features: Vec::new(),
                classes: Vec::new(),
                held_points: Vec::new(),
                held_classes: Vec::new(),
                held_features: Vec::new(),
            };
            for (i, (p, y)) in f.points.iter().zip(feats).enumerate() {
                let held = unit(mix_all(&[setup.seed, t as u64, i as u64, 0x401D])) < setup.holdout;
                if held {
                    out.held_points.push(p.position);
                    out.held_classes.push(p.class);
                    out.held_features.push(y);
                } else {
                    let s = latentbki::key::to_map_frame(&inv, p.position);
                    out.points.push(s);
                    // What the maps compute from (pose, sensor point): every method keys the same position.
                    out.map_points
                        .push(latentbki::key::to_map_frame(&f.pose, s));
                    out.features.push(y);
                    out.classes.push(p.class);
                }
            }
            out
        })
        .collect()
}

/// A method in the comparison.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Decode each held-out point's own feature.
    Segmentation,
    /// Last observation in the voxel wins.
    Heuristic,
    /// VLMap-style running mean.
    VlmapMean,
    /// ConvBKI-style categorical BKI with filter size f.
    ConvBki(u8),
    /// LatentBKI on the f32 reference map with filter size f.
    LatentBki(u8),
    /// LatentBKI on the quantized device map with filter size f.
    OnDevice(u8),
    /// The same, fed int8 features: the PCA features quantized with one global scale (an accelerator's
    /// output), set from the first frame.
    OnDeviceInt8(u8),
}

impl Method {
    /// The table row name.
    pub fn label(&self) -> String {
        match self {
            Self::Segmentation => "Segmentation only".into(),
            Self::Heuristic => "Heuristic (last wins)".into(),
            Self::VlmapMean => "VLMap-style mean (f = 1)".into(),
            Self::ConvBki(f) => format!("ConvBKI-style categorical (f = {f})"),
            Self::LatentBki(f) => format!("LatentBKI f32 (f = {f})"),
            Self::OnDevice(f) => format!("LatentBKI on-device, quantized (f = {f})"),
            Self::OnDeviceInt8(f) => format!("LatentBKI on-device, int8 features (f = {f})"),
        }
    }
    /// Whether the method quantifies uncertainty.
    pub fn has_uncertainty(&self) -> bool {
        matches!(
            self,
            Self::LatentBki(_) | Self::OnDevice(_) | Self::OnDeviceInt8(_)
        )
    }
    /// The comparison of the paper's tables, plus the device map.
    pub fn all() -> Vec<Method> {
        Self::for_filter(3)
    }
    /// The comparison with the kernel methods at filter size `f` (`--filter-size`; the paper's is 3).
    pub fn for_filter(f: u8) -> Vec<Method> {
        let mut methods = vec![
            Self::Segmentation,
            Self::Heuristic,
            Self::VlmapMean,
            Self::ConvBki(f),
            Self::LatentBki(1),
            Self::LatentBki(f),
            Self::OnDevice(f),
            Self::OnDeviceInt8(f),
        ];
        methods.dedup(); // f = 1
        methods
    }
}

/// The final state and score of one method.
pub struct MethodResult {
    /// Which method.
    pub method: Method,
    /// Confusion matrix over every held-out point of every frame.
    pub confusion: Confusion,
    /// Voxels in the final map.
    pub voxels: usize,
    /// Wall time of integration and evaluation, seconds.
    pub seconds: f64,
    /// Per held-out point uncertainties (only for the method asked to score them).
    pub scored: Vec<ScoredPoint>,
    /// The final map.
    pub mapper: Box<dyn MappingMethod>,
}

fn with_filter(config: &MapConfig, f: u8) -> anyhow::Result<MapConfig> {
    MapConfig::new(
        config.voxel_size(),
        config.kernel_length(),
        f,
        config.prior(),
        config.mode(),
    )
    .map_err(|e| anyhow::anyhow!("filter size {f}: {e}"))
}

fn build(
    method: Method,
    config: &MapConfig,
    dec: &Decoding,
    setup: &ExperimentSettings,
    link: Option<Box<dyn Radio>>,
) -> anyhow::Result<Box<dyn MappingMethod>> {
    let e = |e: latentbki::ConfigError| anyhow::anyhow!("{}: {e}", method.label());
    Ok(match method {
        Method::Segmentation => Box::new(SegmentationOnly),
        Method::Heuristic => Box::new(Heuristic::new(*config)),
        Method::VlmapMean => Box::new(RunningMean::new(*config)),
        Method::ConvBki(f) => {
            Box::new(CategoricalBki::new(with_filter(config, f)?, dec.decoder.clone()).map_err(e)?)
        }
        Method::LatentBki(f) => Box::new(
            LatentBki::new(with_filter(config, f)?)
                .map_err(|err| anyhow::anyhow!("{}: {err}", method.label()))?,
        ),
        Method::OnDevice(f) => Box::new(
            OnDevice::new(
                with_filter(config, f)?,
                setup.device_window,
                dec.mean_weights,
                link.map(|mut l| {
                    l.feature_space(&dec.classes, &dec.pca, &dec.decoder);
                    l
                }),
            )
            .map_err(|err| anyhow::anyhow!("{}: {err:?}", method.label()))?,
        ),
        Method::OnDeviceInt8(f) => Box::new(
            OnDevice::new(
                with_filter(config, f)?,
                setup.device_window,
                dec.mean_weights,
                None,
            )
            .map_err(|err| anyhow::anyhow!("{}: {err:?}", method.label()))?
            .with_int8_features(),
        ),
    })
}

/// The uncertainties of one voxel for the sparsification analysis, with `category` the class it is
/// predicted as (the query whose score the sampling varies); `None` where λ ≤ 2 (every measure is gated
/// there, as in the authors' code).
pub fn uncertainties(
    v: &VoxelStats<D>,
    decoder: &Decoder,
    category: usize,
    draws: usize,
    sampler: &mut Sampler<D>,
) -> Option<Uncertainties> {
    let tvar = v.optimality(Spread::AuthorsTVar)?;
    let cov = v.optimality(Spread::StudentTCovariance)?;
    Some(Uncertainties {
        e_tvar: tvar.e,
        d_tvar: tvar.d,
        e_cov: cov.e,
        d_cov: cov.d,
        sampling_authors: sampler.score_variance(
            SamplingMode::Authors,
            v,
            decoder,
            category,
            draws,
        )?,
        sampling_sound: sampler.score_variance(SamplingMode::Sound, v, decoder, category, draws)?,
    })
}

/// Every uncertainty of one voxel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Uncertainties {
    /// E-optimality, authors' t_var.
    pub e_tvar: f32,
    /// D-optimality, authors' t_var.
    pub d_tvar: f32,
    /// E-optimality, Student-t covariance.
    pub e_cov: f32,
    /// D-optimality, Student-t covariance.
    pub d_cov: f32,
    /// Sampling, the authors' procedure.
    pub sampling_authors: f32,
    /// Sampling, the model's predictive with the cosine score.
    pub sampling_sound: f32,
}

pub(super) fn run_one(
    method: Method,
    inputs: &Inputs<'_>,
    score: bool,
    link: Option<Box<dyn Radio>>,
    bar: &ProgressBar,
) -> anyhow::Result<MethodResult> {
    let Inputs {
        frames,
        config,
        dec,
        setup,
    } = *inputs;
    let start = Instant::now();
    let mut mapper = build(method, config, dec, setup, link)?;
    let mut confusion = Confusion::new(dec.classes.len());
    let mut scored = Vec::new();
    for (t, f) in frames.iter().enumerate() {
        mapper.integrate(f);
        let mut sampler = Sampler::<D>::new(mix_all(&[setup.seed, t as u64, 0x5A3]));
        for (i, ((p, c), own)) in f
            .held_points
            .iter()
            .zip(&f.held_classes)
            .zip(&f.held_features)
            .enumerate()
        {
            let pred = mapper.predict(&dec.decoder, *p, own);
            confusion.add(usize::from(*c), pred);
            if score {
                if let (Some(pred), Some(v)) = (pred, mapper.posterior(*p)) {
                    if let Some(u) =
                        uncertainties(&v, &dec.decoder, pred, setup.sampling_draws, &mut sampler)
                    {
                        scored.push(ScoredPoint {
                            truth: *c,
                            predicted: pred as u16,
                            e_opt: u.e_tvar,
                            d_opt: u.d_tvar,
                            e_opt_cov: u.e_cov,
                            d_opt_cov: u.d_cov,
                            sampling: u.sampling_authors,
                            sampling_sound: u.sampling_sound,
                            random: unit(mix_all(&[setup.seed, t as u64, i as u64, 0x3A4D])),
                        });
                    }
                }
            }
        }
        bar.inc(1);
    }
    mapper.finish(&dec.decoder);
    Ok(MethodResult {
        method,
        voxels: mapper.voxels(),
        confusion,
        seconds: start.elapsed().as_secs_f64(),
        scored,
        mapper,
    })
}

/// What every method of a run shares: the frames, the map configuration, the decoding and the setup.
#[derive(Clone, Copy)]
pub struct Inputs<'a> {
    /// The encoded frames.
    pub frames: &'a [EncodedFrame],
    /// The scene's map configuration (methods change the filter size).
    pub config: &'a MapConfig,
    /// PCA, codebook, encoder.
    pub dec: &'a Decoding,
    /// The experiment's settings.
    pub setup: &'a ExperimentSettings,
}

/// How heavy a run of `m` is per point, for scheduling: the kernel's reach f³ dominates, and the device map
/// also quantizes and streams its evictions (about four times the f32 map's time).
pub(super) fn weight(m: &Method) -> u64 {
    match m {
        Method::OnDevice(f) | Method::OnDeviceInt8(f) => 4 * (10 + u64::from(*f).pow(3)),
        Method::LatentBki(f) => 10 + u64::from(*f).pow(3),
        Method::ConvBki(f) => 5 + u64::from(*f).pow(3),
        _ => 1,
    }
}

pub(super) fn points(frames: &[EncodedFrame]) -> u64 {
    frames.iter().map(|f| f.points.len() as u64).sum()
}
