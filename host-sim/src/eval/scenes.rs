//! The two experiments the CLI runs — the real LiDAR tile and the procedural house — from scene to table,
//! curves and pictures.
//!
//! The PCA is always fitted on a different sequence than the one evaluated: for the tile, another loop
//! phase with other sensor and network seeds; indoors, another generated house.
//!
//! The tile scene maps the committed tile or the user's own `.las`/`.laz` ([`SceneOptions::tile`]) with
//! the map configuration of [`SceneOptions::tile_config`]; a run whose sensor saw too few points stops
//! with one line saying what to change ([`SceneSource::check_enough`]).

use super::experiment::{self, Method, MethodResult, Setup, SweepPoint};
use super::figures::{self, TopDown};
use super::methods::{Decoder, Radio};
use super::sparsification::{self, Sparsification};
use crate::cli_args::{MapArgs, TileArgs};
use crate::sim::indoor::{self, IndoorRun, IndoorScene, IndoorSensor};
use crate::sim::scale;
use crate::sim::sensor::{DepthCamera, MultizoneTof, RangeLidar};
use crate::sim::tile::{self, significant, Tile, TileRun};
use crate::sim::vocab::Vocabulary;
use crate::sim::{mix_all, Sequence};
use anyhow::{bail, Context, Result};
use latentbki::MapConfig;
use std::path::{Path, PathBuf};

/// Which scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scene {
    /// The real labelled LiDAR tile.
    Tile,
    /// The procedural house.
    Indoor,
}

impl Scene {
    /// Name used for directories and tables.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Tile => "tile",
            Self::Indoor => "indoor",
        }
    }
    /// The device map's window radius at the default sensors: the sensor's range plus the kernel's reach
    /// (the LiDAR sees 10 m; the camera's 6 m depth limit is up to 8 m of range in the image corners). A
    /// scaled or `--range` LiDAR widens it: [`SceneSource::device_window`].
    pub fn device_window(&self) -> f32 {
        match self {
            Self::Tile => 11.0,
            Self::Indoor => 8.5,
        }
    }
    /// The default free-text query pictured for this scene (for the tile, [`tile_query`] picks one from the
    /// classes it has).
    pub fn default_query(&self) -> &'static str {
        match self {
            Self::Tile => "house",
            Self::Indoor => "kitchen",
        }
    }
}

/// The query pictured on a tile: a word for one of the classes the tile has — another word than the class
/// name where the vocabulary has one (the open-vocabulary case: "house" finds buildings), in this order of
/// preference — else the name of its first named class; `None` when every class is a user code.
pub fn tile_query(classes: &[String], vocab: &Vocabulary) -> Option<String> {
    const SYNONYMS: [(&str, &str); 11] = [
        ("building", "house"),
        ("high vegetation", "tree"),
        ("water", "water"),
        ("road surface", "road"),
        ("bridge deck", "bridge"),
        ("transmission tower", "tower"),
        ("conductor wire", "wire"),
        ("medium vegetation", "vegetation"),
        ("low vegetation", "grass"),
        ("rail", "rail"),
        ("ground", "dirt"),
    ];
    SYNONYMS
        .iter()
        .find(|(class, _)| classes.iter().any(|c| c == class))
        .map(|(_, word)| word.to_string())
        .or_else(|| classes.iter().find(|c| vocab.get(c).is_ok()).cloned())
}

/// Scene-side options.
#[derive(Clone, Debug)]
pub struct SceneOptions {
    /// Frames on the tile loop.
    pub tile_frames: usize,
    /// Points per frame on the tile (LiDAR budget).
    pub tile_points: usize,
    /// Pixels per frame indoors (camera budget).
    pub indoor_pixels: usize,
    /// Seed of the house layout.
    pub layout_seed: u64,
    /// Indoor sensor: the multizone ToF instead of the depth camera.
    pub indoor_tof: bool,
    /// Budgets of the sparsity sweep (empty = no sweep), per scene.
    pub sweep_tile: Vec<usize>,
    /// Indoor sweep budgets.
    pub sweep_indoor: Vec<usize>,
    /// Filter sizes of the sweep.
    pub sweep_filters: Vec<u8>,
    /// Queries to picture (the scene's default if empty).
    pub queries: Vec<String>,
    /// The tile scene's point cloud (default: the committed tile) and flight.
    pub tile: TileArgs,
    /// The tile scene's map configuration (default: the paper's outdoor one).
    pub tile_config: MapConfig,
    /// With `Some`, the tile's map configuration is taken from these options, the voxel size and kernel
    /// length that are not given chosen from the tile's point spacing ([`scale`]); `tile_config` is unused.
    pub tile_map: Option<MapArgs>,
}

impl Default for SceneOptions {
    fn default() -> Self {
        Self {
            tile_frames: 60,
            tile_points: 3000,
            indoor_pixels: DepthCamera::default().pixels_per_frame,
            layout_seed: 1,
            indoor_tof: false,
            sweep_tile: vec![100, 300, 1000, 3000],
            sweep_indoor: vec![100, 300, 1000, 3072],
            sweep_filters: vec![1, 3, 5],
            queries: Vec::new(),
            tile: TileArgs::default(),
            tile_config: MapConfig::default(),
            tile_map: None,
        }
    }
}

/// Builds a scene's sequence at a given sensor budget; `train` selects the PCA training sequence.
pub struct SceneSource {
    scene: Scene,
    tile: Option<Tile>,
    /// The LiDAR's range and flying height over the tile, metres.
    tile_flight: (f32, f32),
    /// The tile scene's map configuration.
    tile_config: MapConfig,
    /// The scale used and where it came from, one phrase (the tile scene).
    scale_note: String,
    houses: Option<(IndoorScene, IndoorScene)>,
    options: SceneOptions,
    seed: u64,
}

impl SceneSource {
    /// Load (tile) or generate (houses) the scene.
    pub fn new(scene: Scene, options: &SceneOptions, seed: u64) -> Result<Self> {
        let (tile, houses) = match scene {
            Scene::Tile => {
                let t = &options.tile;
                t.check()?;
                let tile = match &t.las {
                    None => Tile::builtin_in(t.units).context("loading the built-in LAS tile")?,
                    // One line: the option, the file and what is wrong with it.
                    Some(path) => Tile::read(path, &t.read_options())
                        .map_err(|e| anyhow::anyhow!("--las {}: {e}", path.display()))?,
                };
                (Some(tile), None)
            }
            Scene::Indoor => (
                None,
                Some((
                    IndoorScene::generate(options.layout_seed),
                    IndoorScene::generate(mix_all(&[options.layout_seed, 0x7EA1])),
                )),
            ),
        };
        let (tile_flight, tile_config, scale_note) = match &tile {
            Some(t) => Self::tile_scale(t, options)?,
            None => ((0.0, 0.0), options.tile_config, String::new()),
        };
        Ok(Self {
            scene,
            tile,
            tile_flight,
            tile_config,
            scale_note,
            houses,
            options: options.clone(),
            seed,
        })
    }

    /// The tile's map configuration, sensor range and flying height, and one phrase saying where they came
    /// from: given (the options, or the paper's defaults for the built-in tile) or measured from the tile.
    fn tile_scale(t: &Tile, options: &SceneOptions) -> Result<((f32, f32), MapConfig, String)> {
        let (range, _) = tile::scaled_sensor(t, options.tile_points);
        let flight_given = options.tile.range.is_some();
        let range = options.tile.range.unwrap_or(range);
        let altitude = options.tile.altitude.unwrap_or(range / 5.0);
        let (config, map_note) = match &options.tile_map {
            Some(map) => {
                let voxel = scale::voxel_for_spacing(t.spacing);
                let config = map.config_with_voxel(voxel)?;
                let note = match (map.voxel_size.is_some(), map.kernel_length.is_some()) {
                    (false, false) => format!(
                        "from the points' spacing ≈ {} m: voxel ≈ spacing, ℓ = {} voxels",
                        significant(t.spacing),
                        scale::KERNEL_VOXELS
                    ),
                    (true, true) => "given".to_string(),
                    (true, false) => format!("voxel given, ℓ = {} voxels", scale::KERNEL_VOXELS),
                    (false, true) => format!(
                        "ℓ given, voxel from the points' spacing ≈ {} m",
                        significant(t.spacing)
                    ),
                };
                (config, note)
            }
            None if options.tile == TileArgs::default()
                && options.tile_config == MapConfig::default() =>
            {
                (
                    options.tile_config,
                    "given: the paper's outdoor configuration".to_string(),
                )
            }
            None => (options.tile_config, "given".to_string()),
        };
        let flight_note = if flight_given {
            "given".to_string()
        } else {
            format!(
                "from the density: 4 frames of {} points in range, at least {} m",
                options.tile_points,
                significant(scale::scaled_sensor_floor(t.spacing))
            )
        };
        let voxel = config.voxel_size();
        let window = scale::window_voxels(range, voxel, config.filter_size());
        if !scale::window_fits(window) {
            let max = latentbki::local_map::MAX_WINDOW_VOXELS as f32;
            bail!(
                "the LiDAR's range ({} m) spans {window:.0} voxels of {voxel} m, and the device map's window holds at most {max:.0}: give --voxel-size {} or more, or a --range below {} m",
                significant(range),
                significant(scale::preferred_at_least((range + 1.0) / (0.9 * max))),
                significant(0.9 * max * voxel),
            );
        }
        let note = format!(
            "voxel {} m, ℓ = {} m ({map_note}); LiDAR range {} m, flying {} m above the ground ({flight_note})",
            significant(voxel),
            significant(config.kernel_length()),
            significant(range),
            significant(altitude),
        );
        Ok(((range, altitude), config, note))
    }

    /// The scale the tile scene uses and where it came from (empty indoors).
    pub fn scale_note(&self) -> &str {
        &self.scale_note
    }

    /// The map configuration of this scene's runs.
    pub fn config(&self) -> MapConfig {
        match self.scene {
            Scene::Tile => self.tile_config,
            Scene::Indoor => MapConfig::default(),
        }
    }

    /// The scene's sequence with `budget` points (tile) or pixels (camera) per frame.
    pub fn sequence(&self, budget: usize, train: bool) -> Sequence {
        let seed = if train {
            mix_all(&[self.seed, 0x7EA1])
        } else {
            self.seed
        };
        match self.scene {
            Scene::Tile => {
                let run = TileRun {
                    frames: self.options.tile_frames,
                    lidar: RangeLidar {
                        points_per_frame: budget,
                        range_m: self.tile_flight.0,
                        ..RangeLidar::default()
                    },
                    altitude: self.tile_flight.1,
                    seed,
                    phase: if train { 0.5 } else { 0.0 },
                    config: self.tile_config,
                };
                tile::sequence(self.tile.as_ref().expect("tile loaded"), &run)
            }
            Scene::Indoor => {
                let (test, training) = self.houses.as_ref().expect("houses generated");
                let sensor = if self.options.indoor_tof {
                    IndoorSensor::Tof(MultizoneTof::default())
                } else {
                    IndoorSensor::Camera(DepthCamera {
                        pixels_per_frame: budget,
                        ..DepthCamera::default()
                    })
                };
                let run = IndoorRun {
                    layout_seed: self.options.layout_seed,
                    seed,
                    sensor,
                    ..IndoorRun::default()
                };
                indoor::sequence(if train { training } else { test }, &run)
            }
        }
    }

    /// The tile, if this is the tile scene.
    pub fn tile(&self) -> Option<&Tile> {
        self.tile.as_ref()
    }

    /// The table's title: the scene, or the user's file.
    pub fn title(&self) -> String {
        match &self.options.tile.las {
            Some(path) if self.scene == Scene::Tile => format!(
                "tile {}",
                path.file_name()
                    .unwrap_or(path.as_os_str())
                    .to_string_lossy()
            ),
            _ => self.scene.name().into(),
        }
    }

    /// The device map's window radius: the sensor's range plus the kernel's reach (at least 1 m).
    pub fn device_window(&self, config: &MapConfig) -> f32 {
        match self.scene {
            Scene::Tile => {
                self.tile_flight.0
                    + (f32::from(config.filter_size()) * config.voxel_size()).max(1.0)
            }
            Scene::Indoor => self.scene.device_window(),
        }
    }

    /// A run needs more than D points in the training sequence (to fit the D-component PCA) and in the
    /// test sequence: otherwise stop with one line that says what to change.
    pub fn check_enough(&self, train: &Sequence, test: &Sequence) -> Result<()> {
        let need = super::methods::D + 1;
        let seen = train.points().min(test.points());
        if seen >= need {
            return Ok(());
        }
        let frames = test.frames.len();
        match (self.scene, &self.tile) {
            (Scene::Tile, Some(t)) if t.points.len() < need => {
                let advice = if (t.points.len() as u64) < t.file_points {
                    "raise --max-points, or use a larger tile"
                } else {
                    "use a larger tile"
                };
                bail!(
                    "too few points: {} holds {} usable points and the {}-component feature PCA needs at least {need}: {advice}",
                    self.title(),
                    t.points.len(),
                    super::methods::D,
                )
            }
            (Scene::Tile, Some(t)) => {
                let (lo, hi) = t.bounds;
                let (range, altitude) = self.tile_flight;
                let advice = if altitude >= range {
                    "lower --altitude below the range, or raise --range"
                } else {
                    "raise --range, --points or --frames"
                };
                bail!(
                    "too sparse: the robot's LiDAR saw {seen} points in {frames} frames over {} ({:.0} × {:.0} m, {:.1} points/m², range {:.1} m, flying {:.1} m above the ground), and the {}-component feature PCA needs at least {need}: {advice}",
                    self.title(),
                    hi[0] - lo[0],
                    hi[1] - lo[1],
                    t.points.len() as f32 / t.area().max(1e-6),
                    range,
                    altitude,
                    super::methods::D,
                )
            }
            _ => bail!(
                "too sparse: the camera saw {seen} points in {frames} frames, and the {}-component feature PCA needs at least {need}: raise --pixels",
                super::methods::D
            ),
        }
    }

    /// When the LatentBKI map (filter size `f`) left more than 20 % of the held-out tile points in voxels
    /// no integrated point reached, one line that says what to change: voxels about the size of the tile's
    /// point spacing (the kernel length kept at five voxels, the paper's ratio), or more frames.
    pub fn coverage_hint(&self, results: &[MethodResult], f: u8) -> Option<String> {
        let (Scene::Tile, Some(t)) = (self.scene, &self.tile) else {
            return None;
        };
        let r = results.iter().find(|r| r.method == Method::LatentBki(f))?;
        let unknown = r.confusion.unknown() as f64 / r.confusion.total().max(1) as f64;
        if unknown <= 0.2 {
            return None;
        }
        let spacing = (t.area() as f64 / t.points.len().max(1) as f64).sqrt();
        let voxel = self.tile_config.voxel_size();
        let advice = if spacing > 1.5 * f64::from(voxel) {
            let v = (spacing * 20.0).round() / 20.0;
            format!(
                "try --voxel-size {v:.2} --kernel-length {:.2} (about the spacing), or more --frames",
                5.0 * v
            )
        } else {
            "give more --frames or --points".to_string()
        };
        Some(format!(
            "hint: {:.0} % of the held-out points fell in voxels no integrated point reached; the tile's points are ≈ {spacing:.2} m apart and the voxels {voxel} m: {advice}",
            100.0 * unknown
        ))
    }

    /// The default budget of the main run.
    pub fn budget(&self) -> usize {
        match self.scene {
            Scene::Tile => self.options.tile_points,
            Scene::Indoor => self.options.indoor_pixels,
        }
    }
}

/// Everything one scene's experiment produced.
pub struct Report {
    /// Scene.
    pub scene: Scene,
    /// Method results, in table order.
    pub results: Vec<MethodResult>,
    /// Sparsification of the LatentBKI f = 3 map's uncertainty.
    pub sparsification: Sparsification,
    /// The sparsity sweep (empty if not run).
    pub sweep: Vec<SweepPoint>,
    /// The Markdown section for this scene.
    pub markdown: String,
    /// PNGs written.
    pub figures: Vec<PathBuf>,
    /// One line saying what to change when the map left most held-out points unknown.
    pub hint: Option<String>,
}

/// Run one scene's experiment and write its pictures into `out/<scene>/`.
pub fn run(
    scene: Scene,
    options: &SceneOptions,
    setup: &Setup,
    out: &Path,
    sweep: bool,
    link: Option<Box<dyn Radio>>,
) -> Result<Report> {
    let vocab = Vocabulary::builtin();
    let source = SceneSource::new(scene, options, setup.seed)?;
    if let (Some(t), Some(_)) = (source.tile(), &options.tile.las) {
        println!(
            "{}: {}; map scale: {}",
            source.title(),
            t.summary(),
            source.scale_note()
        );
    }
    let train = source.sequence(source.budget(), true);
    let test = source.sequence(source.budget(), false);
    source.check_enough(&train, &test)?;
    let setup = &Setup {
        device_window: source.device_window(&test.config),
        ..*setup
    };
    let dec = experiment::decoding(&vocab, &train, setup)?;
    let frames = experiment::encode(&test, &dec, setup);
    let f = test.config.filter_size();
    let methods = Method::for_filter(f);
    let budgets = match scene {
        Scene::Tile => &options.sweep_tile,
        Scene::Indoor => &options.sweep_indoor,
    };
    let sweep = if sweep && !budgets.is_empty() {
        experiment::Sweep::new(
            &|b| source.sequence(b, false),
            budgets,
            &options.sweep_filters,
            &dec,
            setup,
        )
    } else {
        experiment::Sweep::none()
    };
    let (results, sweep_points) = experiment::run_with_sweep(
        &methods,
        &experiment::Inputs {
            frames: &frames,
            config: &test.config,
            dec: &dec,
            setup,
        },
        Some(Method::LatentBki(f)),
        link,
        &sweep,
        &format!("{}: methods and sweep", scene.name()),
    )?;
    drop(sweep);
    let scored = &results
        .iter()
        .find(|r| r.method == Method::LatentBki(f))
        .expect("LatentBKI ran at the scene's filter size")
        .scored;
    let spars = sparsification::analyse(scored, dec.classes.len());

    // Pictures, from the on-device map (what the robot holds plus what it streamed).
    let dir = out.join(scene.name());
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let device = results
        .iter()
        .find(|r| matches!(r.method, Method::OnDevice(_)))
        .or_else(|| results.iter().find(|r| r.method == Method::LatentBki(f)))
        .expect("a LatentBKI map ran");
    let snap = device.mapper.snapshot();
    let top = TopDown::new(&snap, &test.config, test.cutaway_height);
    let which = device.method.label();
    let mut figs = Vec::new();
    let fig = |e: Box<dyn std::error::Error + Send + Sync>| anyhow::anyhow!("drawing: {e}");
    let p = dir.join("semantic_map.png");
    figures::semantic_map(
        &p,
        &format!("{}: top-down semantic map ({which})", scene.name()),
        &top,
        &test.config,
        &dec.decoder,
        &dec.classes,
    )
    .map_err(fig)?;
    figs.push(p);
    let queries: Vec<String> = if options.queries.is_empty() {
        match scene {
            Scene::Tile => tile_query(&dec.classes, &vocab).into_iter().collect(),
            Scene::Indoor => vec![scene.default_query().to_string()],
        }
    } else {
        options.queries.clone()
    };
    for q in &queries {
        let cb =
            Decoder::from_pca(&dec.pca, &[*vocab.get(q)?]).map_err(|e| anyhow::anyhow!("{e}"))?;
        let p = dir.join(format!("query_{}.png", q.replace(' ', "_")));
        figures::query_heatmap(&p, q, &top, &test.config, &cb).map_err(fig)?;
        figs.push(p);
    }
    let p = dir.join("uncertainty_eopt.png");
    figures::uncertainty_map(
        &p,
        &format!("{}: E-optimality, authors' t_var ({which})", scene.name()),
        &top,
        &test.config,
    )
    .map_err(fig)?;
    figs.push(p);
    let p = dir.join("sparsification.png");
    figures::sparsification_plot(&p, scene.name(), &spars).map_err(fig)?;
    figs.push(p);
    if !sweep_points.is_empty() {
        let p = dir.join("sparsity_sweep.png");
        figures::sweep_plot(&p, scene.name(), &sweep_points).map_err(fig)?;
        figs.push(p);
    }

    let held: usize = frames.iter().map(|f| f.held_points.len()).sum();
    let integrated: usize = frames.iter().map(|f| f.points.len()).sum();
    let notes = format!(
        "{} frames, {:.0} points per frame ({} integrated, {} held out); PCA 384 → 64 fitted on another sequence keeps {:.1} % of the variance; {}. Unknown = held-out points whose voxel the map had not observed (counted wrong).",
        frames.len(),
        test.points() as f64 / test.frames.len().max(1) as f64,
        integrated,
        held,
        100.0 * dec.explained_variance,
        if source.scale_note().is_empty() {
            format!(
                "voxel {} m, ℓ = {} m",
                test.config.voxel_size(),
                test.config.kernel_length()
            )
        } else {
            format!("map scale: {}", source.scale_note())
        },
    );
    let mut md =
        super::tables::results_table(&format!("Scene: {}", source.title()), &results, &notes);
    if let Some(r) = results.iter().find(|r| r.method == Method::LatentBki(f)) {
        md += &format!(
            "\nmIoU above averages the classes present in the ground truth ({} of {}); averaged as the authors' evaluation does (all {} classes, an absent class counting 0), LatentBKI f32 (f = {f}) has {:.2} %.\n",
            (0..r.confusion.classes()).filter(|&c| r.confusion.iou(c).is_some()).count(),
            r.confusion.classes(),
            r.confusion.classes(),
            100.0 * r.confusion.miou_authors()
        );
    }
    md += &super::tables::iou_table(&dec.classes, &results);
    md += &format!(
        "\nUncertainty of LatentBKI (f = {f}) vs error, {} held-out points with λ > 2 — AUSE (lower is better; accuracy / mIoU points). Sampling: {} draws, variance of the predicted class's score:\n\n| Uncertainty | AUSE acc. | AUSE mIoU |\n|---|---:|---:|\n",
        spars.points, setup.sampling_draws
    );
    for (name, a, m) in &spars.ause {
        md += &format!("| {name} | {:.2} | {:.2} |\n", 100.0 * a, 100.0 * m);
    }
    if !sweep_points.is_empty() {
        md += "\nSparsity sweep (LatentBKI f32): accuracy / mIoU (%) by points per frame\n\n| points/frame |";
        let filters = &options.sweep_filters;
        for f in filters {
            md += &format!(" f = {f} |");
        }
        md += "\n|---:|";
        md += &"---:|".repeat(filters.len());
        md += "\n";
        for &b in budgets {
            let row: Vec<&SweepPoint> = sweep_points.iter().filter(|p| p.budget == b).collect();
            if let Some(first) = row.first() {
                md += &format!("| {:.0} |", first.points_per_frame);
                for p in &row {
                    md += &format!(" {:.2} / {:.2} |", 100.0 * p.accuracy, 100.0 * p.miou);
                }
                md += "\n";
            }
        }
    }
    let hint = source.coverage_hint(&results, f);
    Ok(Report {
        scene,
        results,
        sparsification: spars,
        sweep: sweep_points,
        markdown: md,
        figures: figs,
        hint,
    })
}
