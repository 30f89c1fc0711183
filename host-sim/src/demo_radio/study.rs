//! `demo --codec-study`: where the base station's error comes from, and what other summary codecs would
//! buy, measured on the demo's own robot map in seconds instead of one demo run per design.
//!
//! Each of the robot's voxels (its residencies merged, so one summary per voxel: the demo sends 1.10) is
//! encoded and decoded with a candidate codec, merged into a fresh map, and every posterior in reach is
//! compared with the robot's own map (what the wire alone costs) and with the f32 reference of all points.
//! Bytes are the summaries' quantized parts only (key, residency and count add ≈ 5 B on the wire); the
//! entropy column is what an ideal entropy coder of the mean codes (one symbol table per band and bit
//! width, fixed for the whole run) would send instead of the packed codes: ≈ 1 B per summary, too little
//! for an entropy coder's flash on the robot.

use super::against;
use crate::eval::methods::{Decoder, D};
use crate::ObsMap;
use latentbki::key::VoxelKey;
use latentbki::obs::ObsStats;
use latentbki::stats::VoxelStats;
use latentbki::wire::rice::Policy;
use latentbki::wire::{decode_codes, encode_codes, encode_rice, wire_count, SummaryCodec};
use std::collections::HashMap;

/// One candidate's measured effect.
struct Row {
    codec: SummaryCodec,
    policy: Option<Policy>,
    code_bytes: f64,
    entropy_bytes: f64,
    vs_robot: (f64, f64),
    vs_reference: (f64, f64),
}

/// The table: candidate codecs, each against the robot's map and the reference.
pub fn table(
    config: latentbki::MapConfig,
    robot: &[(VoxelKey, ObsStats<D>)],
    robot_posteriors: &[(VoxelKey, VoxelStats<D>)],
    reference: &[(VoxelKey, VoxelStats<D>)],
    decoder: &Decoder,
) -> String {
    let mut rows = Vec::new();
    // (mean bits, growth, lead, lead bits): protocol 3's demo codec and its neighbours, then lead bands.
    for (mean_bits, growth, lead, lead_bits) in [(3, 3, 8, 3), (4, 3, 8, 3)] {
        let codec = SummaryCodec {
            mean_bits,
            psi_blocks: super::CODEC.psi_blocks,
            mean_bits_growth: growth,
            lead,
            lead_bits,
            rice: false,
        };
        rows.push(row(
            config,
            (codec, None),
            robot,
            robot_posteriors,
            reference,
            decoder,
        ));
    }
    // Rice-coded means: the step policy's offsets (lead, rest) and shrink per doubling, in eighths.
    let policies = std::env::var("LATENTBKI_RICE_STUDY").ok();
    let grid: Vec<(u8, u8, u8, u8, i8)> = match &policies {
        Some(s) => s
            .split(';')
            .filter_map(|p| {
                let v: Vec<i32> = p.split(',').filter_map(|x| x.trim().parse().ok()).collect();
                (v.len() == 5).then(|| (v[0] as u8, v[1] as u8, v[2] as u8, v[3] as u8, v[4] as i8))
            })
            .collect(),
        None => vec![(48, 48, 4, 0, 0), (48, 52, 4, 0, 8)],
    };
    for (lead_eighths, rest_eighths, lead_per_doubling, rest_per_doubling, rest_single) in grid {
        let policy = Policy {
            lead_eighths,
            rest_eighths,
            lead_per_doubling,
            rest_per_doubling,
            rest_single,
        };
        // LATENTBKI_RICE_LEAD: another lead band length for the Rice rows.
        let lead = std::env::var("LATENTBKI_RICE_LEAD")
            .ok()
            .and_then(|l| l.parse().ok())
            .unwrap_or(super::CODEC.lead);
        rows.push(row(
            config,
            (
                SummaryCodec {
                    lead,
                    ..super::CODEC
                },
                Some(policy),
            ),
            robot,
            robot_posteriors,
            reference,
            decoder,
        ));
    }
    let n = robot.len().max(1) as f64;
    let points: f64 = robot.iter().map(|(_, o)| f64::from(o.count)).sum();
    let mut out = format!(
        "codec study: {} voxels (one summary each), {:.2} points per voxel; per voxel: quantized bytes, \
         ideal entropy-coded bytes; vs robot map: argmax %, RMS; vs f32 reference: argmax %, RMS\n",
        robot.len(),
        points / n
    );
    out += &spectrum(robot);
    for r in rows {
        if let Some(p) = r.policy {
            out += &format!(
                "  Rice, lead {:2}, steps ‖m‖/2^({}/8) − {}/8, ‖m‖/2^({}/8) − {}/8 per doubling of n (+{}/8 at n = 1): {:6.2} B; robot {:6.2} % {:.4}; reference {:6.2} % {:.4}\n",
                r.codec.lead,
                p.lead_eighths,
                p.lead_per_doubling,
                p.rest_eighths,
                p.rest_per_doubling,
                p.rest_single,
                r.code_bytes / n,
                100.0 * r.vs_robot.0,
                r.vs_robot.1,
                100.0 * r.vs_reference.0,
                r.vs_reference.1,
            );
            continue;
        }
        out += &format!(
            "  mean bits {} + growth {}, lead {:2} at +{}: {:6.2} B, entropy {:6.2} B; robot {:6.2} % {:.4}; reference {:6.2} % {:.4}\n",
            r.codec.mean_bits,
            r.codec.mean_bits_growth,
            r.codec.lead,
            r.codec.lead_bits,
            r.code_bytes / n,
            r.entropy_bytes / n,
            100.0 * r.vs_robot.0,
            r.vs_robot.1,
            100.0 * r.vs_reference.0,
            r.vs_reference.1,
        );
    }
    out
}

fn row(
    config: latentbki::MapConfig,
    (codec, policy): (SummaryCodec, Option<Policy>),
    robot: &[(VoxelKey, ObsStats<D>)],
    robot_posteriors: &[(VoxelKey, VoxelStats<D>)],
    reference: &[(VoxelKey, VoxelStats<D>)],
    decoder: &Decoder,
) -> Row {
    let mut map = ObsMap::<D>::new(config).expect("the robot's configuration");
    let mut buf = vec![0u8; codec.code_len(D)];
    let mut code_bytes = 0usize;
    // Histogram of mean codes per band and bit width.
    let mut hist: HashMap<(bool, u32), Vec<u64>> = HashMap::new();
    for (k, o) in robot {
        let count = wire_count(o.count).unwrap_or(1);
        let len = match policy {
            Some(p) => encode_rice::<D>(codec, p, o, count, &mut buf),
            None => encode_codes::<D>(codec, o, &mut buf),
        }
        .expect("a valid codec");
        code_bytes += len;
        if policy.is_some() {
            let dec = decode_codes::<D>(codec, o.count, &buf[..len]).expect("just encoded");
            map.merge_observations(*k, &dec);
            continue;
        }
        // Mean codes: the lead band after its scale byte, the others after theirs.
        let lead = usize::from(codec.lead);
        let rest_at = 8 * (codec.lead_len_for(count) + 1);
        for i in 0..D {
            let (bits, at) = if i < lead {
                let b = codec.lead_bits_for(count);
                (b, 8 + i * b as usize)
            } else {
                let b = codec.rest_bits_for(count);
                (b, rest_at + (i - lead) * b as usize)
            };
            let h = hist
                .entry((i < lead, bits))
                .or_insert_with(|| vec![0; 1 << bits as usize]);
            let mut q = 0usize;
            for b in 0..bits as usize {
                q |= usize::from(buf[(at + b) / 8] >> ((at + b) % 8) & 1) << b;
            }
            h[q] += 1;
        }
        let dec = decode_codes::<D>(codec, o.count, &buf[..len]).expect("just encoded");
        map.merge_observations(*k, &dec);
    }
    // The packed mean codes replaced by their ideal entropy-coded length.
    let mut entropy_bytes = code_bytes as f64;
    for ((_, bits), h) in &hist {
        let total: u64 = h.iter().sum();
        let ent: f64 = h
            .iter()
            .filter(|&&c| c > 0)
            .map(|&c| {
                let p = c as f64 / total as f64;
                -p * p.log2()
            })
            .sum();
        entropy_bytes -= total as f64 * (f64::from(*bits) - ent) / 8.0;
    }
    let ours: HashMap<VoxelKey, VoxelStats<D>> = map.posteriors_sorted().into_iter().collect();
    let vs_robot = against(&ours, robot_posteriors, decoder);
    let vs_reference = against(&ours, reference, decoder);
    Row {
        codec,
        policy,
        code_bytes: code_bytes as f64,
        entropy_bytes,
        vs_robot: (vs_robot.0, vs_robot.1),
        vs_reference: (vs_reference.0, vs_reference.1),
    }
}

/// Per-voxel ‖Δμ‖/‖μ‖ of `got` against `reference`: voxels it cannot answer, and over the answered ones
/// the RMS, p95 and max.
pub fn profile(
    got: &HashMap<VoxelKey, VoxelStats<D>>,
    reference: &[(VoxelKey, VoxelStats<D>)],
) -> String {
    let mut errs = Vec::with_capacity(reference.len());
    let mut missing = 0usize;
    // Squared relative error in the 8 leading components and in the others.
    let (mut lead_sq, mut all_sq) = (0.0f64, 0.0f64);
    for (k, r) in reference {
        let Some(b) = got.get(k) else {
            missing += 1;
            continue;
        };
        let den: f64 = r.mean.iter().map(|x| f64::from(x * x)).sum();
        let num: f64 = b
            .mean
            .iter()
            .zip(&r.mean)
            .map(|(x, y)| f64::from((x - y) * (x - y)))
            .sum();
        let lead: f64 = b.mean[..8]
            .iter()
            .zip(&r.mean[..8])
            .map(|(x, y)| f64::from((x - y) * (x - y)))
            .sum();
        lead_sq += lead / den.max(1e-12);
        all_sq += num / den.max(1e-12);
        errs.push((num / den.max(1e-12)).sqrt());
    }
    errs.sort_by(f64::total_cmp);
    let rms = (errs.iter().map(|e| e * e).sum::<f64>() / errs.len().max(1) as f64).sqrt();
    let q = |p: f64| {
        errs.get(((errs.len() as f64 - 1.0) * p) as usize)
            .copied()
            .unwrap_or(0.0)
    };
    format!(
        "{missing} of {} unanswered; answered: RMS {rms:.4}, median {:.4}, p95 {:.4}, p99 {:.4}, max {:.4}; \
         {:.0} % of the squared error in the 8 leading components",
        reference.len(),
        q(0.5),
        q(0.95),
        q(0.99),
        q(1.0),
        100.0 * lead_sq / all_sq.max(1e-30)
    )
}

/// The robot's voxel means' energy per component (PCA order): the first 8 one by one, then the mean per 8;
/// for one-point voxels and the others.
fn spectrum(robot: &[(VoxelKey, ObsStats<D>)]) -> String {
    let mut out = String::new();
    for (name, one) in [("n = 1", true), ("n >= 2", false)] {
        let mut ms = [0.0f64; D];
        let mut c = 0usize;
        for (_, o) in robot.iter().filter(|(_, o)| (o.count < 1.5) == one) {
            c += 1;
            for (m, v) in ms.iter_mut().zip(&o.mean) {
                *m += f64::from(v * v);
            }
        }
        let c = c.max(1) as f64;
        let first: Vec<String> = ms[..8].iter().map(|m| format!("{:.1e}", m / c)).collect();
        let bands: Vec<String> = ms
            .chunks(8)
            .map(|b| format!("{:.1e}", b.iter().sum::<f64>() / 8.0 / c))
            .collect();
        out += &format!(
            "  mean energy per component, {name}: first 8 {}; per 8 {}\n",
            first.join(" "),
            bands.join(" ")
        );
    }
    out
}
