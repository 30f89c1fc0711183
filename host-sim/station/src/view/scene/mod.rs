//! The map's layers as Foxglove scene entities: one `SceneEntity` of cubes per 8 × 8 × 8-voxel block.
//!
//! [`DecodedMap`] keeps what the view shows of every observed voxel (a [`VoxelRow`]: its decoded class, the
//! query's cosine score, its E-optimality and the robots that observed it), decoded from the map with the
//! same calls `map-query` makes ([`GlobalMap::posterior`], [`Codebook::argmax`], [`Codebook::score`]), so the view
//! and the command agree voxel for voxel. A change of one voxel changes the posteriors of every observed
//! voxel within the kernel's reach, so [`DecodedMap::update`] re-decodes those too and reports the blocks
//! they fall in; only those blocks' entities are sent again. The exact value of every cube is in its
//! entity's metadata (one comma-separated list per entity, in cube order), which Foxglove shows on
//! selection and which the tests read back.
//!
//! **Each block's entity is encoded once per layer and kept** until the block, or the layer's colour
//! range, changes: a full scene — what a late joiner gets — is then those bytes joined ([`DecodedMap::full_bytes`]),
//! not every cube built and encoded again (`host-sim view-bench` prints both; the cache costs about one
//! encoded layer per layer, ≈ 12 MB each at 100k voxels). Joining is exact protobuf: `entities` is a
//! repeated field, so a `SceneUpdate` holding only one entity encodes as that entity's tag, length and
//! bytes, and such encodings joined after the deletions are one valid `SceneUpdate`. A cached entity keeps
//! the timestamp it was built at (when its block last changed).

use crate::export::{label_colour, ramp};
use crate::global_map::GlobalMap;
use foxglove::messages::{
    scene_entity_deletion, Color, CubePrimitive, KeyValuePair, Pose, Quaternion, SceneEntity,
    SceneEntityDeletion, SceneUpdate, Timestamp, Vector3,
};
use latentbki::{decode::Codebook, inference::Spread, key::VoxelKey};
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fmt::Write as _;

/// Voxels per block side: 2^3 = 8, so a block holds at most 512 cubes.
pub const BLOCK_SHIFT: i32 = 3;

/// The frame every entity is in (the map's frame, metres).
pub const FRAME: &str = "map";

/// A block of 8 × 8 × 8 voxels: the unit of an incremental update.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct BlockKey {
    /// Block index along x.
    pub x: i32,
    /// Block index along y.
    pub y: i32,
    /// Block index along z.
    pub z: i32,
}

impl BlockKey {
    /// The block a voxel is in.
    pub fn of(k: VoxelKey) -> Self {
        Self {
            x: k.x >> BLOCK_SHIFT,
            y: k.y >> BLOCK_SHIFT,
            z: k.z >> BLOCK_SHIFT,
        }
    }
    /// The entity id of this block (the same on every layer's topic).
    pub fn id(&self) -> String {
        format!("block {} {} {}", self.x, self.y, self.z)
    }
}

/// One layer of the view: one topic of `foxglove.SceneUpdate`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Layer {
    /// Each voxel coloured by its decoded class (the legend is on [`super::LEGEND_TOPIC`]).
    Classes,
    /// The query phrase's cosine score (viridis ramp over the scores when the phrase was set).
    Heat,
    /// E-optimality in the authors' convention (their `t_var`, λ > 2), viridis ramp over log E.
    Uncertainty,
    /// Which robot observed the voxel (palette by robot id; white: several robots).
    Robots,
}

impl Layer {
    /// Every layer.
    pub const ALL: [Layer; 4] = [
        Layer::Classes,
        Layer::Heat,
        Layer::Uncertainty,
        Layer::Robots,
    ];
    /// Its topic.
    pub fn topic(self) -> &'static str {
        match self {
            Layer::Classes => "/map/classes",
            Layer::Heat => "/map/heat",
            Layer::Uncertainty => "/map/uncertainty",
            Layer::Robots => "/map/robots",
        }
    }
    /// The metadata key of its per-cube values.
    pub fn key(self) -> &'static str {
        match self {
            Layer::Classes => "class",
            Layer::Heat => "score",
            Layer::Uncertainty => "e_optimality",
            Layer::Robots => "robots",
        }
    }
}

/// What the view shows of one observed voxel.
#[derive(Clone, Debug, PartialEq)]
pub struct VoxelRow<const D: usize> {
    /// Posterior mean (kept so a new phrase is scored without gathering again).
    pub mean: [f32; D],
    /// Best class and its cosine score (None without a vocabulary).
    pub class: Option<(usize, f32)>,
    /// The query's cosine score (None without a query).
    pub heat: Option<f32>,
    /// E-optimality, authors' convention (None for λ ≤ 2).
    pub e_opt: Option<f32>,
    /// Robots whose contributions the voxel holds, ascending.
    pub robots: Vec<u16>,
}

/// Colour ranges, fixed between full scenes so that an unchanged cube keeps its colour.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Range {
    lo: f32,
    hi: f32,
}

impl Range {
    /// From the 2nd to the 98th percentile of the finite values (a few outliers must not squeeze every
    /// other voxel into one colour); [0, 1] without any.
    fn over(values: impl Iterator<Item = f32>) -> Self {
        let mut v: Vec<f32> = values.filter(|v| v.is_finite()).collect();
        if v.is_empty() {
            return Self { lo: 0.0, hi: 1.0 };
        }
        v.sort_unstable_by(f32::total_cmp);
        let at = |q: f32| v[((q * (v.len() - 1) as f32).round() as usize).min(v.len() - 1)];
        Self {
            lo: at(0.02),
            hi: at(0.98),
        }
    }
    fn t(&self, v: f32) -> f32 {
        ((v - self.lo) / (self.hi - self.lo).max(1e-6)).clamp(0.0, 1.0)
    }
}

/// Grey for a voxel without a value on a layer.
const UNDEFINED: [u8; 3] = [128, 128, 128];

/// The view's copy of the decoded map, block by block.
pub struct DecodedMap<const D: usize, const K: usize> {
    voxel_size: f32,
    rows: HashMap<VoxelKey, VoxelRow<D>>,
    blocks: BTreeMap<BlockKey, BTreeSet<VoxelKey>>,
    heat_range: Range,
    log_e_range: Option<Range>,
    /// Each class's colour (by index; a class past its end takes the index palette).
    palette: Vec<[u8; 3]>,
    /// Per layer, each block's entity encoded as a one-entity `SceneUpdate` (see the module's doc).
    encoded: [BTreeMap<BlockKey, Vec<u8>>; 4],
}

impl<const D: usize, const K: usize> DecodedMap<D, K> {
    /// An empty scene for voxels of this size (metres).
    pub fn new(voxel_size: f32) -> Self {
        Self {
            voxel_size,
            rows: HashMap::new(),
            blocks: BTreeMap::new(),
            heat_range: Range { lo: 0.0, hi: 1.0 },
            log_e_range: None,
            palette: Vec::new(),
            encoded: Default::default(),
        }
    }

    /// Voxels in the scene.
    pub fn len(&self) -> usize {
        self.rows.len()
    }
    /// Whether the scene holds no voxel.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }
    /// A voxel's row.
    pub fn row(&self, k: &VoxelKey) -> Option<&VoxelRow<D>> {
        self.rows.get(k)
    }
    /// The observed voxels and their rows, block by block.
    pub fn voxels(&self) -> impl Iterator<Item = (&VoxelKey, &VoxelRow<D>)> {
        self.blocks.values().flatten().map(|k| (k, &self.rows[k]))
    }
    /// Voxel side, metres.
    pub fn voxel_size(&self) -> f32 {
        self.voxel_size
    }
    /// Blocks holding at least one voxel.
    pub fn blocks(&self) -> impl Iterator<Item = &BlockKey> {
        self.blocks.keys()
    }

    /// Colour the classes so (index order); the classes layer is built again.
    pub fn set_palette(&mut self, colours: Vec<[u8; 3]>) {
        self.palette = colours;
        self.encoded[Layer::Classes as usize].clear();
    }

    /// A class's colour.
    pub fn class_colour(&self, class: usize) -> [u8; 3] {
        self.palette
            .get(class)
            .copied()
            .unwrap_or_else(|| label_colour(class))
    }

    /// Voxels per decoded class (`classes` entries; a voxel without a class is not counted).
    pub fn class_counts(&self, classes: usize) -> Vec<usize> {
        let mut counts = vec![0; classes];
        for c in self.rows.values().filter_map(|r| r.class) {
            if let Some(n) = counts.get_mut(c.0) {
                *n += 1;
            }
        }
        counts
    }

    /// The centre of the scene's extent, metres: on each axis the middle of the 5th and 95th percentiles
    /// of the voxels' centres (a stray voxel far away does not move it). None for an empty scene.
    pub fn centre(&self) -> Option<[f32; 3]> {
        if self.rows.is_empty() {
            return None;
        }
        let mut out = [0.0; 3];
        for (axis, o) in out.iter_mut().enumerate() {
            let mut v: Vec<i32> = self.rows.keys().map(|k| [k.x, k.y, k.z][axis]).collect();
            v.sort_unstable();
            let at = |q: f32| v[((q * (v.len() - 1) as f32).round() as usize).min(v.len() - 1)];
            *o = (at(0.05) + at(0.95) + 1) as f32 * 0.5 * self.voxel_size;
        }
        Some(out)
    }

    /// Observed voxels whose posterior a change of `changed` alters: each changed voxel and every
    /// observed voxel within the kernel's reach of it.
    pub fn affected(
        map: &GlobalMap<D>,
        changed: impl IntoIterator<Item = VoxelKey>,
    ) -> Vec<VoxelKey> {
        let r = map.map_config().reach();
        let mut out = BTreeSet::new();
        for k in changed {
            for dx in -r..=r {
                for dy in -r..=r {
                    for dz in -r..=r {
                        let n = VoxelKey::new(k.x + dx, k.y + dy, k.z + dz);
                        if map.voxel(&n).is_some() {
                            out.insert(n);
                        }
                    }
                }
            }
        }
        out.into_iter().collect()
    }

    /// Decode `keys` from `map` again (a key the map no longer holds leaves the scene); returns the
    /// blocks whose entities changed.
    pub fn update(
        &mut self,
        map: &GlobalMap<D>,
        keys: &[VoxelKey],
        vocab: Option<&Codebook<D, K>>,
        query: Option<&Codebook<D, K>>,
    ) -> BTreeSet<BlockKey> {
        let mut dirty = BTreeSet::new();
        for &k in keys {
            let block = BlockKey::of(k);
            let row = map.voxel(&k).and_then(|v| {
                let p = map.posterior(&k)?;
                let mut robots: Vec<u16> = v
                    .closed
                    .iter()
                    .chain(v.live.iter().map(|c| &c.id))
                    .map(|id| id.robot)
                    .collect();
                robots.sort_unstable();
                robots.dedup();
                Some(VoxelRow {
                    mean: p.mean,
                    class: vocab.and_then(|cb| cb.argmax(&p.mean)),
                    heat: query.map(|q| q.score(&p.mean, 0)),
                    e_opt: p.optimality(Spread::AuthorsTVar).map(|o| o.e),
                    robots,
                })
            });
            let changed = match row {
                Some(row) => {
                    self.blocks.entry(block).or_default().insert(k);
                    self.rows.insert(k, row.clone()) != Some(row)
                }
                None => {
                    if let Some(b) = self.blocks.get_mut(&block) {
                        b.remove(&k);
                        if b.is_empty() {
                            self.blocks.remove(&block);
                        }
                    }
                    self.rows.remove(&k).is_some()
                }
            };
            if changed {
                dirty.insert(block);
            }
        }
        for cache in &mut self.encoded {
            for b in &dirty {
                cache.remove(b);
            }
        }
        dirty
    }

    /// Score every voxel against a new query (or none) and fix the heat colour range to its scores.
    pub fn set_query(&mut self, query: Option<&Codebook<D, K>>) {
        for row in self.rows.values_mut() {
            row.heat = query.map(|q| q.score(&row.mean, 0));
        }
        self.heat_range = Range::over(self.rows.values().filter_map(|r| r.heat));
        self.encoded[Layer::Heat as usize].clear();
    }

    /// Fix the colour ranges to the values now in the scene (at a full scene).
    pub fn fix_ranges(&mut self) {
        self.heat_range = Range::over(self.rows.values().filter_map(|r| r.heat));
        let logs = self
            .rows
            .values()
            .filter_map(|r| r.e_opt.filter(|e| *e > 0.0).map(f32::ln));
        self.log_e_range = Some(Range::over(logs));
        self.encoded[Layer::Heat as usize].clear();
        self.encoded[Layer::Uncertainty as usize].clear();
    }

    /// The colour a layer paints a voxel.
    pub fn colour(&self, layer: Layer, row: &VoxelRow<D>) -> [u8; 3] {
        match layer {
            Layer::Classes => row.class.map_or(UNDEFINED, |(c, _)| self.class_colour(c)),
            Layer::Heat => row.heat.map_or(UNDEFINED, |s| ramp(self.heat_range.t(s))),
            Layer::Uncertainty => match (row.e_opt.filter(|e| *e > 0.0), self.log_e_range) {
                (Some(e), Some(r)) => ramp(r.t(e.ln())),
                (Some(_), None) => ramp(0.5),
                (None, _) => UNDEFINED,
            },
            Layer::Robots => match row.robots.as_slice() {
                [one] => label_colour(usize::from(*one)),
                [] => UNDEFINED,
                _ => [255, 255, 255],
            },
        }
    }

    /// The value a layer shows of a voxel, as its metadata lists it (empty: none).
    fn value(layer: Layer, row: &VoxelRow<D>, out: &mut String) {
        let _ = match layer {
            Layer::Classes => row.class.map(|(c, _)| write!(out, "{c}")),
            Layer::Heat => row.heat.map(|s| write!(out, "{s}")),
            Layer::Uncertainty => row.e_opt.map(|e| write!(out, "{e}")),
            Layer::Robots => {
                for (i, r) in row.robots.iter().enumerate() {
                    let _ = write!(out, "{}{r}", if i > 0 { "+" } else { "" });
                }
                None
            }
        };
    }
}

mod messages;
pub use messages::encode;

#[cfg(test)]
mod tests;
