//! The two scenes the CLI evaluates — the real LiDAR tile and the procedural house: their sequences,
//! sensors and map scale. [`run`] (in `scene_report`) takes one from scene to table, curves and pictures.
//!
//! The PCA is always fitted on a different sequence than the one evaluated: for the tile, another loop
//! phase with other sensor and network seeds; indoors, another generated house.
//!
//! The tile scene maps the committed tile or the user's own `.las`/`.laz` ([`SceneOptions::tile`]) with
//! the map configuration of [`SceneOptions::tile_config`]; a run whose sensor saw too few points stops
//! with one line saying what to change ([`SceneSource::check_enough`]).

mod checks;
mod tile_scale;
use tile_scale::{window_error, TileScale};

use super::experiment::{Method, MethodResult};
pub use super::scene_report::{run, Report};
use crate::cli_args::{MapArgs, ScaleArg, TileArgs};
use crate::sim::indoor::{self, IndoorRun, IndoorScene, IndoorSensor};
use crate::sim::sensor::{DepthCamera, MultizoneTof, RangeLidar};
use crate::sim::tile::{self, significant, survey, Tile, TileRun};
use crate::sim::vocab::TextEmbeddings;
use crate::sim::{flight_plan, scale};
use crate::sim::{mix_all, Sequence};
use anyhow::{bail, Context, Result};
use latentbki::MapConfig;

/// Which scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SceneKind {
    /// The real labelled LiDAR tile.
    Tile,
    /// The procedural house.
    Indoor,
}

impl SceneKind {
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
pub fn tile_query(classes: &[String], vocab: &TextEmbeddings) -> Option<String> {
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
    /// length that are not given chosen from the tile's point spacing: by validation
    /// ([`super::scale_search`]) or by the spacing rule ([`scale`]); `tile_config` is unused.
    pub tile_map: Option<MapArgs>,
    /// On the survey flight, plan the number of frames from the tile (each surface observed by about as
    /// many frames as on the built-in tile) instead of flying `tile_frames`.
    pub plan_frames: bool,
    /// Print nothing (the tile's summary and the flight's figure): a run made only to learn the scale.
    pub quiet: bool,
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
            plan_frames: true,
            quiet: false,
        }
    }
}

/// Builds a scene's sequence at a given sensor budget; `train` selects the PCA training sequence.
pub struct SceneSource {
    scene: SceneKind,
    tile: Option<Tile>,
    /// The LiDAR's range and flying height over the tile, metres.
    tile_flight: (f32, f32),
    /// Frames flown over the tile, and whether on the revisiting survey.
    tile_frames: usize,
    tile_survey: bool,
    /// The survey's plan, when its frames were planned.
    plan: Option<flight_plan::Plan>,
    /// The tile scene's map configuration (provisional when it is to be chosen by validation).
    tile_config: MapConfig,
    /// Whether the tile's scale is chosen by validation ([`super::scale_search`]), and the largest
    /// filter size it may choose.
    validate: Option<u8>,
    /// The scale used and where it came from, one phrase (the tile scene).
    scale_note: String,
    /// The flight and where it came from, one phrase (the tile scene).
    flight_note: String,
    /// The frames flown and why that many ("; …").
    frames_note: String,
    houses: Option<(IndoorScene, IndoorScene)>,
    options: SceneOptions,
    seed: u64,
}

impl SceneSource {
    /// Load (tile) or generate (houses) the scene.
    pub fn new(scene: SceneKind, options: &SceneOptions, seed: u64) -> Result<Self> {
        let (tile, houses) = match scene {
            SceneKind::Tile => {
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
            SceneKind::Indoor => (
                None,
                Some((
                    IndoorScene::generate(options.layout_seed),
                    IndoorScene::generate(mix_all(&[options.layout_seed, 0x7EA1])),
                )),
            ),
        };
        let scale = match &tile {
            Some(t) => Self::tile_scale(t, options)?,
            None => TileScale {
                flight: (0.0, 0.0),
                config: options.tile_config,
                validate: None,
                note: String::new(),
                flight_note: String::new(),
            },
        };
        let survey = options.tile.survey();
        let (tile_frames, plan) = match &tile {
            Some(t) if survey && options.plan_frames => {
                let run = TileRun {
                    lidar: RangeLidar {
                        points_per_frame: options.tile_points,
                        range_m: scale.flight.0,
                        ..RangeLidar::default()
                    },
                    altitude: scale.flight.1,
                    ..TileRun::default()
                };
                let plan = flight_plan::plan(t, &run, flight_plan::builtin_frames_per_surface());
                (plan.frames, Some(plan))
            }
            _ => (options.tile_frames, None),
        };
        let frames_note = if tile.is_none() {
            String::new()
        } else {
            match (&plan, survey) {
                (Some(p), _) => format!(
                    "; {} frames planned: {} laps of a survey over the {} cells of {} m that hold points",
                    p.frames,
                    p.laps,
                    p.lap_len,
                    significant(scale.flight.0)
                ) + &if p.budget < options.tile_points {
                    format!(
                        ", {} points per frame (a quarter of the {} in range: the tile holds fewer than four frames' budget of {} there)",
                        p.budget,
                        4 * p.budget,
                        options.tile_points
                    )
                } else {
                    String::new()
                },
                (None, true) => format!("; {tile_frames} frames (given) of a survey over the cells that hold points"),
                (None, false) => format!("; {tile_frames} frames on a loop over the middle"),
            }
        };
        Ok(Self {
            scene,
            tile,
            tile_flight: scale.flight,
            tile_frames,
            tile_survey: survey,
            plan,
            tile_config: scale.config,
            validate: scale.validate,
            scale_note: scale.note,
            flight_note: scale.flight_note,
            frames_note,
            houses,
            options: options.clone(),
            seed,
        })
    }

    /// The LiDAR's range over the tile, metres.
    pub fn range(&self) -> f32 {
        self.tile_flight.0
    }

    /// The revisiting survey's plan, when its frames were planned from the tile.
    pub fn plan(&self) -> Option<&flight_plan::Plan> {
        self.plan.as_ref()
    }

    /// The largest filter size the scale search may choose, when the tile's scale is chosen by validation
    /// (`None`: the scale is given or follows the spacing rule).
    pub fn validates_scale(&self) -> Option<u8> {
        self.validate
    }

    /// Why the robot's map cannot hold the window the sensor's range asks for at `config`, if it cannot.
    pub fn device_refusal(&self, config: &MapConfig) -> Option<String> {
        if self.scene != SceneKind::Tile {
            return None;
        }
        let range = self.tile_flight.0;
        let window = scale::window_voxels(range, config.voxel_size(), config.filter_size());
        (!scale::window_fits(window)).then(|| window_error(range, config))
    }

    /// The flight's figure: how many frames return each of the tile's points (median, 5th percentile,
    /// share never returned) for a sequence flown over it, against the built-in tile's.
    pub fn frames_per_surface(&self, seq: &Sequence) -> Option<String> {
        let t = self.tile.as_ref()?;
        let poses: Vec<_> = seq.frames.iter().map(|f| f.pose).collect();
        let lidar = RangeLidar {
            points_per_frame: self.budget(),
            range_m: self.tile_flight.0,
            ..RangeLidar::default()
        };
        let counts = survey::frames_per_surface(t, &poses, &lidar);
        let never =
            counts.iter().filter(|&&c| c <= 0.0).count() as f32 / counts.len().max(1) as f32;
        Some(format!(
            "frames per surface: each of the tile's points is returned by {:.1} frames (median; 5th percentile {:.1}; {:.1} % never) — the built-in tile's flight: {:.1}",
            survey::median(&counts),
            survey::quantile(&counts, 0.05),
            100.0 * never,
            flight_plan::builtin_frames_per_surface()
        ))
    }

    /// The scale the tile scene uses and where it came from (empty indoors).
    pub fn scale_note(&self) -> &str {
        &self.scale_note
    }

    /// The map configuration of this scene's runs.
    pub fn config(&self) -> MapConfig {
        match self.scene {
            SceneKind::Tile => self.tile_config,
            SceneKind::Indoor => MapConfig::default(),
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
            SceneKind::Tile => {
                let run = TileRun {
                    frames: self.tile_frames,
                    survey: self.tile_survey,
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
            SceneKind::Indoor => {
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
            Some(path) if self.scene == SceneKind::Tile => format!(
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
            SceneKind::Tile => {
                self.tile_flight.0
                    + (f32::from(config.filter_size()) * config.voxel_size()).max(1.0)
            }
            SceneKind::Indoor => self.scene.device_window(),
        }
    }

    /// The training and the test sequence at the scene's budget, checked ([`Self::check_enough`]); a
    /// user's own tile (`--las`) is announced first, with its summary and map scale.
    pub fn train_and_test(&self) -> Result<(Sequence, Sequence)> {
        if let (Some(t), Some(_), false) = (self.tile(), &self.options.tile.las, self.options.quiet)
        {
            if self.validate.is_some() {
                println!(
                    "{}: {}; flight: {}{}; map scale: chosen by validation (below)",
                    self.title(),
                    t.summary(),
                    self.flight_note,
                    self.frames_note
                );
            } else {
                println!(
                    "{}: {}; map scale: {}{}",
                    self.title(),
                    t.summary(),
                    self.scale_note(),
                    self.frames_note
                );
            }
        }
        let train = self.sequence(self.budget(), true);
        let test = self.sequence(self.budget(), false);
        self.check_enough(&train, &test)?;
        if self.tile.is_some()
            && !self.options.quiet
            && (self.options.tile.las.is_some() || self.tile_survey)
        {
            if let Some(line) = self.frames_per_surface(&test) {
                println!("{line}");
            }
        }
        Ok((train, test))
    }

    /// The default budget of the main run (on a planned survey, the plan's: at most a quarter of the points
    /// in range).
    pub fn budget(&self) -> usize {
        match self.scene {
            SceneKind::Tile => self
                .plan
                .as_ref()
                .map_or(self.options.tile_points, |p| p.budget),
            SceneKind::Indoor => self.options.indoor_pixels,
        }
    }
}
