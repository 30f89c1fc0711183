//! `demo --codec-study`: where the base station's error comes from, and what other summary codecs would
//! buy, measured on the demo's own robot map in seconds instead of one demo run per design.
//!
//! Each of the robot's voxels (its residencies merged, so one summary per voxel: the demo sends 1.10) is
//! encoded and decoded with a candidate codec, merged into a fresh map, and every posterior in reach is
//! compared with the robot's own map (what the wire alone costs) and with the f32 reference of all points.
//! Bytes are the summaries' quantized parts only (key, residency and count add ≈ 5 B on the wire); the
//! entropy column is what an ideal entropy coder of the mean codes (one symbol table per bit width, fixed
//! for the whole run) would send instead of the packed codes.

use super::against;
use crate::eval::methods::{Decoder, D};
use crate::ObsMap;
use latentbki::key::VoxelKey;
use latentbki::obs::ObsStats;
use latentbki::stats::VoxelStats;
use latentbki::wire::{decode_codes, encode_codes, wire_count, SummaryCodec};
use std::collections::HashMap;

/// One candidate's measured effect.
struct Row {
    codec: SummaryCodec,
    code_bytes: f64,
    entropy_bytes: f64,
    vs_robot: (f64, f64),
    vs_reference: (f64, f64),
}

/// The table: candidates by mean bits and growth, each against the robot's map and the reference.
pub fn table(
    config: latentbki::MapConfig,
    robot: &[(VoxelKey, ObsStats<D>)],
    robot_posteriors: &[(VoxelKey, VoxelStats<D>)],
    reference: &[(VoxelKey, VoxelStats<D>)],
    decoder: &Decoder,
) -> String {
    let mut rows = Vec::new();
    for (mean_bits, growth) in [
        (2, 4),
        (3, 3),
        (3, 4),
        (3, 5),
        (4, 2),
        (4, 3),
        (4, 4),
        (5, 3),
    ] {
        let codec = SummaryCodec {
            mean_bits,
            psi_blocks: super::CODEC.psi_blocks,
            mean_bits_growth: growth,
            lead: 0,
            lead_bits: 0,
        };
        rows.push(row(
            config,
            codec,
            robot,
            robot_posteriors,
            reference,
            decoder,
        ));
    }
    // The means' energy per component (PCA order), for one-point voxels and for the others.
    for (name, keep) in [("n = 1", true), ("n >= 2", false)] {
        let mut ms = [0.0f64; D];
        let mut c = 0usize;
        for (_, o) in robot.iter().filter(|(_, o)| (o.count < 1.5) == keep) {
            c += 1;
            for (m, v) in ms.iter_mut().zip(&o.mean) {
                *m += f64::from(v * v);
            }
        }
        let am = ms.iter().sum::<f64>() / D as f64;
        let gm = (ms.iter().map(|m| m.max(1e-30).ln()).sum::<f64>() / D as f64).exp();
        let bands: Vec<String> = ms
            .chunks(8)
            .map(|b| format!("{:.2e}", b.iter().sum::<f64>() / 8.0 / c.max(1) as f64))
            .collect();
        let first: Vec<String> = ms[..8]
            .iter()
            .map(|m| format!("{:.1e}", m / c.max(1) as f64))
            .collect();
        println!("first 8: {}", first.join(" "));
        println!("spectrum {name} ({c} voxels): per 8 components {}; coding gain AM/GM {:.2} = {:.2} bits", bands.join(" "), am / gm, 0.5 * (am / gm).log2());
    }
    let n = robot.len().max(1) as f64;
    let points: f64 = robot.iter().map(|(_, o)| f64::from(o.count)).sum();
    let mut out = format!(
        "codec study: {} voxels (one summary each), {:.2} points per voxel; per voxel: quantized bytes, \
         ideal entropy-coded bytes; vs robot map: argmax %, RMS; vs f32 reference: argmax %, RMS\n",
        robot.len(),
        points / n
    );
    for r in rows {
        out += &format!(
            "  mean bits {} + growth {}: {:6.2} B, entropy {:6.2} B; robot {:6.2} % {:.4}; reference {:6.2} % {:.4}\n",
            r.codec.mean_bits,
            r.codec.mean_bits_growth,
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
    codec: SummaryCodec,
    robot: &[(VoxelKey, ObsStats<D>)],
    robot_posteriors: &[(VoxelKey, VoxelStats<D>)],
    reference: &[(VoxelKey, VoxelStats<D>)],
    decoder: &Decoder,
) -> Row {
    let mut map = ObsMap::<D>::new(config).expect("the robot's configuration");
    let mut buf = vec![0u8; codec.code_len(D)];
    let mut code_bytes = 0usize;
    // Histogram of mean codes per bit width.
    let mut hist: HashMap<u32, Vec<u64>> = HashMap::new();
    for (k, o) in robot {
        let len = encode_codes::<D>(codec, o, &mut buf).expect("a valid codec");
        code_bytes += len;
        let count = wire_count(o.count).unwrap_or(1);
        let bits = codec.bits_for(count);
        let h = hist
            .entry(bits)
            .or_insert_with(|| vec![0; 1 << bits as usize]);
        for i in 0..D {
            let mut q = 0usize;
            for b in 0..bits as usize {
                let at = 8 + i * bits as usize + b;
                q |= usize::from(buf[at / 8] >> (at % 8) & 1) << b;
            }
            h[q] += 1;
        }
        let dec = decode_codes::<D>(codec, o.count, &buf[..len]).expect("just encoded");
        map.merge_observations(*k, &dec);
    }
    // The packed mean codes replaced by their ideal entropy-coded length.
    let mut entropy_bytes = code_bytes as f64;
    for (bits, h) in &hist {
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

/// Quantize `v` in place with `bits` per component against its peak (log-coded up to 1/8 octave), mid-rise,
/// after an orthonormal Hadamard rotation when its length is a power of two. Returns the bytes it takes.
fn quantize_band(v: &mut [f32], bits: u32) -> f64 {
    let n = v.len();
    let rot = n.is_power_of_two() && n > 1;
    if rot {
        fwht(v);
    }
    let peak = v.iter().fold(0.0f32, |a, x| a.max(x.abs()));
    if peak > 0.0 {
        let scale = 2f32.powf((peak.log2() * 8.0).ceil() / 8.0);
        let half = (1u32 << bits) as f32 / 2.0;
        let top = (1u32 << bits) - 1;
        for x in v.iter_mut() {
            let q = (((*x / scale + 1.0) * half) as u32).min(top);
            *x = scale * ((q as f32 + 0.5) / half - 1.0);
        }
    }
    if rot {
        fwht(v);
    }
    1.0 + (n as f64 * f64::from(bits) / 8.0)
}

fn fwht(v: &mut [f32]) {
    let n = v.len();
    let mut h = 1;
    while h < n {
        for i in (0..n).step_by(2 * h) {
            for j in i..i + h {
                let (a, b) = (v[j], v[j + h]);
                v[j] = a + b;
                v[j + h] = a - b;
            }
        }
        h *= 2;
    }
    let k = 1.0 / (n as f32).sqrt();
    for x in v.iter_mut() {
        *x *= k;
    }
}

/// A lead-band candidate: the first `lead` (PCA-leading) components apart with `extra` more bits.
pub fn lead_rows(
    config: latentbki::MapConfig,
    robot: &[(VoxelKey, ObsStats<D>)],
    robot_posteriors: &[(VoxelKey, VoxelStats<D>)],
    reference: &[(VoxelKey, VoxelStats<D>)],
    decoder: &Decoder,
) -> String {
    let mut out = String::new();
    let n = robot.len().max(1) as f64;
    let lg = |n: u32| if n > 1 { n.ilog2() } else { 0 };
    type Bits = Box<dyn Fn(u32) -> u32>;
    let candidates: Vec<(&str, usize, Bits, Bits)> = vec![
        (
            "A: rest 3+g3, lead +3",
            8,
            Box::new(move |n| (6 + lg(n).min(3)).min(8)),
            Box::new(move |n| 3 + lg(n).min(3)),
        ),
        (
            "B: rest 3+g3/2, lead 6+g3",
            8,
            Box::new(move |n| (6 + lg(n).min(3)).min(8)),
            Box::new(move |n| 3 + (lg(n) / 2).min(3)),
        ),
        (
            "C: rest 2 at n=1, lead +3",
            8,
            Box::new(move |n| (6 + lg(n).min(3)).min(8)),
            Box::new(move |n| if n == 1 { 2 } else { 3 + lg(n).min(3) }),
        ),
        (
            "D: rest 3+g(n+1)/2",
            8,
            Box::new(move |n| (6 + lg(n).min(3)).min(8)),
            Box::new(move |n| 3 + ((lg(n) + 1) / 2).min(3)),
        ),
        (
            "E: rest 3 flat, lead 6+g3",
            8,
            Box::new(move |n| (6 + lg(n).min(3)).min(8)),
            Box::new(move |_| 3),
        ),
        (
            "F: rest 2+g3, lead 6+g3",
            8,
            Box::new(move |n| (6 + lg(n).min(3)).min(8)),
            Box::new(move |n| 2 + lg(n).min(3)),
        ),
        (
            "G: lead 6 flat, rest 3+g3",
            8,
            Box::new(move |_| 6),
            Box::new(move |n| 3 + lg(n).min(3)),
        ),
        (
            "H: lead 5+g3, rest 3+g3",
            8,
            Box::new(move |n| (5 + lg(n).min(3)).min(8)),
            Box::new(move |n| 3 + lg(n).min(3)),
        ),
    ];
    for (name, lead, lead_bits, rest_bits) in candidates {
        let mut map = ObsMap::<D>::new(config).expect("the robot's configuration");
        let mut bytes = 0.0;
        for (k, o) in robot {
            let count = wire_count(o.count).unwrap_or(1);
            let mut d = *o;
            let (a, b) = d.mean.split_at_mut(lead);
            bytes += quantize_band(a, lead_bits(count));
            bytes += quantize_band(b, rest_bits(count).min(8));
            if count >= 2 {
                bytes += 1.0 + f64::from(super::CODEC.psi_blocks).div_euclid(2.0).max(1.0);
            }
            map.merge_observations(*k, &d);
        }
        let ours: HashMap<VoxelKey, VoxelStats<D>> = map.posteriors_sorted().into_iter().collect();
        let r = against(&ours, robot_posteriors, decoder);
        let f = against(&ours, reference, decoder);
        out += &format!(
            "  {name}: {:6.2} B; robot {:6.2} % {:.4}; reference {:6.2} % {:.4}\n",
            bytes / n,
            100.0 * r.0,
            r.1,
            100.0 * f.0,
            f.1
        );
    }
    out
}
