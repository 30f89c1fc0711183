//! Two global maps of one configuration merged into the map one base station would hold had it received
//! the frames of both: closed contributions are united (each once, by id) and refolded in id order, live
//! ones keep their newest copy unless the other map closed them — so the result is bit for bit the map of
//! feeding both streams into one base station, in any order.

use super::{fold_stamped, ContributionId, GlobalMap, GlobalVoxel, LiveContribution};
use latentbki::forget::{Forgetting, Stamped};
use latentbki::obs::ObsStats;
use latentbki::wire::SessionConfig;

/// Why two maps cannot be merged.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MergeError {
    /// Different session configurations: their statistics mean different things.
    #[error("{0}")]
    Config(String),
}

/// What a merge did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MergeReport {
    /// Voxels only the other map held.
    pub voxels_added: usize,
    /// Closed contributions taken from the other map.
    pub parts_added: usize,
    /// Closed contributions both maps held (the same final summary: kept once).
    pub parts_shared: usize,
    /// Closed contributions both held with different statistics (kept this map's; a robot that reused a
    /// session id, or two copies that were not the same frame).
    pub parts_conflicting: usize,
}

/// The first difference between two configurations, in words (`None`: equal).
pub fn config_difference(a: &SessionConfig, b: &SessionConfig) -> Option<String> {
    if a == b {
        return None;
    }
    let fields: [(&str, String, String); 11] = [
        (
            "feature spaces",
            format!("{:#010x}", a.feature_space),
            format!("{:#010x}", b.feature_space),
        ),
        ("dimensions", a.dim.to_string(), b.dim.to_string()),
        (
            "voxel sizes",
            format!("{} m", a.voxel_size),
            format!("{} m", b.voxel_size),
        ),
        (
            "kernel lengths",
            format!("{} m", a.kernel_length),
            format!("{} m", b.kernel_length),
        ),
        (
            "filter sizes",
            a.filter_size.to_string(),
            b.filter_size.to_string(),
        ),
        (
            "sub-voxel cells",
            a.subvoxel_cells.to_string(),
            b.subvoxel_cells.to_string(),
        ),
        (
            "priors",
            format!(
                "λ₀ {} μ₀ {} Ψ₀ {}",
                a.prior_lambda, a.prior_mean, a.prior_psi
            ),
            format!(
                "λ₀ {} μ₀ {} Ψ₀ {}",
                b.prior_lambda, b.prior_mean, b.prior_psi
            ),
        ),
        ("codecs", format!("{:?}", a.codec), format!("{:?}", b.codec)),
        (
            "int8 scales",
            a.int8_scale.to_string(),
            b.int8_scale.to_string(),
        ),
        (
            "half-lives",
            a.half_life.to_string(),
            b.half_life.to_string(),
        ),
        (
            "configuration ids",
            format!("{:#010x}", a.id()),
            format!("{:#010x}", b.id()),
        ),
    ];
    fields
        .into_iter()
        .find(|(_, x, y)| x != y)
        .map(|(what, x, y)| format!("different {what} ({x} and {y})"))
}

impl<const D: usize> GlobalMap<D> {
    /// Merge `other` (a map of the same configuration) into this one: the map one base station would hold
    /// had it received both maps' frames (bit for bit, in any order: closed contributions fold in id order).
    pub fn merge(&mut self, other: &GlobalMap<D>) -> Result<MergeReport, MergeError> {
        if let Some(d) = config_difference(&self.config, &other.config) {
            return Err(MergeError::Config(d));
        }
        let forgetting = self.forgetting;
        let mut report = MergeReport::default();
        for (key, theirs) in &other.voxels {
            let v = match self.voxels.get_mut(key) {
                Some(ours) => {
                    merge_voxel(ours, theirs, forgetting.as_ref(), &mut report);
                    ours
                }
                None => {
                    report.voxels_added += 1;
                    report.parts_added += theirs.parts.len();
                    self.voxels.entry(*key).or_insert_with(|| theirs.clone())
                }
            };
            let m = v.merged_stamped(forgetting.as_ref());
            self.merged.set_stamped(*key, &m.obs, m.time);
        }
        if forgetting.is_some() {
            self.set_time(other.time());
        }
        Ok(report)
    }
}

/// `ours` ⊕ `theirs`.
fn merge_voxel<const D: usize>(
    ours: &mut GlobalVoxel<D>,
    theirs: &GlobalVoxel<D>,
    forgetting: Option<&Forgetting>,
    report: &mut MergeReport,
) {
    // Statistics settled without their parts (records before version 4): summed, ours first.
    if theirs.base != ObsStats::EMPTY {
        let mut b = Stamped {
            obs: ours.base,
            time: ours.base_time,
        };
        fold_stamped(
            &mut b,
            forgetting,
            &Stamped {
                obs: theirs.base,
                time: theirs.base_time,
            },
        );
        (ours.base, ours.base_time) = (b.obs, b.time);
    }
    for p in &theirs.parts {
        match ours.parts.binary_search_by_key(&p.id, |q| q.id) {
            Ok(i) if ours.parts[i] == *p => report.parts_shared += 1,
            Ok(_) => report.parts_conflicting += 1,
            // Closed in our base already (an older record): nothing to add.
            Err(_) if ours.closed.binary_search(&p.id).is_ok() => report.parts_shared += 1,
            Err(i) => {
                ours.parts.insert(i, *p);
                report.parts_added += 1;
            }
        }
    }
    for id in &theirs.closed {
        if let Err(i) = ours.closed.binary_search(id) {
            ours.closed.insert(i, *id);
        }
    }
    // Live contributions: none the merged map closed; of two copies, the newer.
    let closed = |id: &ContributionId| ours.closed.binary_search(id).is_ok();
    let mut live: Vec<LiveContribution<D>> = ours
        .live
        .iter()
        .filter(|c| !closed(&c.id))
        .copied()
        .collect();
    for c in theirs.live.iter().filter(|c| !closed(&c.id)) {
        match live.binary_search_by_key(&c.id, |l| l.id) {
            Ok(i) if super::newer(c.seq, live[i].seq) => live[i] = *c,
            Ok(_) => {}
            Err(i) => live.insert(i, *c),
        }
    }
    ours.live = live;
    ours.refold(forgetting);
}
