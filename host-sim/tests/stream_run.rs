//! Whole runs streamed to the base station: the on-device LocalMap evicts as the window moves, voxels are
//! evicted and observed again, two robots overlap — and the global map equals the f32 reference map built
//! from all the points at once, within quantization. Also measures bytes per summary and argmax agreement
//! for the README (`cargo test --release -p host-sim --test stream_run -- --nocapture`).

mod stream_common;

use host_sim::base_station::BaseStation;
use host_sim::link::SplitMix;
use host_sim::ReferenceMap;
use latentbki::wire::{decode_codes, encode_codes, parse_body, Message, SummaryCodec};
use stream_common::*;

/// The path of one robot: out along the road and back over part of it (voxels evicted, then seen again).
fn path(from: f32, to: f32, back_to: f32, y: f32) -> Vec<(f32, f32)> {
    let mut p = Vec::new();
    let mut x = from;
    while x < to {
        p.push((x, y));
        x += 0.25;
    }
    while x > back_to {
        p.push((x, y + 0.4));
        x -= 0.25;
    }
    p
}

struct Run {
    world: World,
    base: BaseStation<D>,
    reference: ReferenceMap<D>,
    robots: Vec<RobotRig>,
}

fn run(codec: SummaryCodec, paths: &[Vec<(f32, f32)>], budget: usize) -> Run {
    let world = World::new(codec);
    let mut reference = ReferenceMap::<D>::new(world.config.map_config().unwrap()).unwrap();
    let mut robots: Vec<RobotRig> = (0..paths.len())
        .map(|i| RobotRig::new(&world, i as u16 + 1, 2.5))
        .collect();
    let mut rng = SplitMix::new(5);
    let steps = paths.iter().map(Vec::len).max().unwrap();
    for s in 0..steps {
        for (r, path) in robots.iter_mut().zip(paths) {
            let Some(&(x, y)) = path.get(s) else { continue };
            let (pose, pts, feats) = scan(&world, &mut rng, x, y, 500, 1.6);
            reference.integrate(&pose, &pts, &feats);
            r.step(&pose, &pts, &feats, budget);
        }
    }
    let mut base = BaseStation::<D>::new(world.config).unwrap();
    base.keep_journal();
    for (i, r) in robots.iter_mut().enumerate() {
        r.finish();
        assert_eq!(
            r.map().rejections().total(),
            0,
            "the robot dropped points ({:?}, {:?}): the test would be meaningless",
            r.map().rejections(),
            r.map().counters()
        );
        feed_chunked(&mut base, &r.uart.0, i as u64);
    }
    Run {
        world,
        base,
        reference,
        robots,
    }
}

/// (summaries, bytes of summaries) in the accepted frames.
fn summary_bytes(base: &BaseStation<D>) -> (usize, usize) {
    let (mut n, mut bytes) = (0, 0);
    for j in base.journal() {
        if let Ok((_, Message::Voxels(b))) = parse_body(&j.body) {
            n += usize::from(b.count);
            bytes += b.summaries.len();
        }
    }
    (n, bytes)
}

#[test]
fn whole_run_with_exact_codes_equals_the_reference_map() {
    // 8-bit means isolate merging from quantization: λ must match (nothing double-counted) and μ closely.
    let codec = SummaryCodec {
        mean_bits: 8,
        psi_blocks: 8,
        mean_bits_growth: 0,
        lead: 0,
        lead_bits: 0,
        rice: false,
    };
    let r = run(codec, &[path(0.5, 11.0, 3.0, 0.0)], 64 * 1024);
    let s = r.base.stats();
    assert_eq!(
        (s.lost, s.decoder.refused(), s.refused.malformed),
        (0, 0, 0)
    );
    // Voxels really were evicted and observed again: some keys have two closed contributions.
    let map = r.base.map().unwrap();
    let revisited = map.voxels().filter(|(_, v)| v.closed.len() >= 2).count();
    assert!(
        revisited > 500,
        "only {revisited} voxels were evicted and observed again"
    );
    assert!(
        map.voxels().all(|(_, v)| v.live.is_empty()),
        "every contribution closed at the end"
    );
    assert!(r.robots[0].live_sent > 0, "live updates were streamed too");
    // Against what the robot evicted (merged in f32): only the wire's 8-bit quantization separates them.
    let (_, agree_w, lambda_w, mu_w) = compare(&r.world, map, &evicted_truth(&r.world, &r.robots));
    // Against the f32 reference of all points: the robot's own compact voxel codes add their error.
    let (n, agree, worst_lambda, rms_mu) = compare(&r.world, map, &reference_truth(&r.reference));
    println!("8-bit wire, one robot: {n} voxels, {revisited} evicted and observed again");
    println!("  vs robot's evictions merged in f32: agreement {agree_w:.4}, worst Δλ/λ {lambda_w:.2e}, RMS ‖Δμ‖/‖μ‖ {mu_w:.4}");
    println!("  vs f32 reference of all points:     agreement {agree:.4}, worst Δλ/λ {worst_lambda:.2e}, RMS ‖Δμ‖/‖μ‖ {rms_mu:.4}");
    assert!(
        lambda_w < 1e-5 && mu_w < 0.01 && agree_w >= 0.999,
        "merge is not exact"
    );
    assert!(worst_lambda < 1e-4, "Σλ not conserved: {worst_lambda}");
    assert!(agree >= 0.99, "{agree}");
    // The robot's own voxel codes (src/quant.rs) dominate μ's error against the reference.
    assert!(rms_mu < 0.05, "{rms_mu}");
    // Every point is counted once.
    assert_eq!(map.observed_points(), r.reference.points() as f64);
}

#[test]
fn default_codec_meets_the_size_and_agreement_goals() {
    let codec = SummaryCodec::DEFAULT;
    let r = run(codec, &[path(0.5, 11.0, 3.0, 0.0)], 64 * 1024);
    let map = r.base.map().unwrap();
    let (n, agree_ref, worst_lambda, rms_mu) =
        compare(&r.world, map, &reference_truth(&r.reference));
    let (_, agree_w, _, mu_w) = compare(&r.world, map, &evicted_truth(&r.world, &r.robots));
    let (count, bytes) = summary_bytes(&r.base);
    let per_summary = bytes as f64 / count as f64;
    let evicted = r.robots[0].evicted.len();
    // `agree_w`: the base station's posteriors vs the robot's own map (its evicted statistics, gathered in
    // f32): only the wire's quantization separates them.
    println!(
        "default codec (b = {}, B = {}): {per_summary:.2} B/summary over {count} summaries ({evicted} evicted voxels); base station vs the robot's own map: argmax agreement {agree_w:.4}, RMS ‖Δμ‖/‖μ‖ {mu_w:.4} ({n} voxels answered); vs the f32 reference: agreement {agree_ref:.4}, worst Δλ/λ {worst_lambda:.2e}, RMS ‖Δμ‖/‖μ‖ {rms_mu:.4}",
        codec.mean_bits,
        codec.psi_blocks,
    );
    assert!(per_summary <= 40.0, "{per_summary} bytes per summary");
    assert!(agree_w >= 0.99, "{agree_w}");
    assert!(agree_ref >= 0.97, "{agree_ref}");
    assert!(worst_lambda < 1e-4);
    assert!(mu_w < 0.1, "{mu_w}");
    let _ = rms_mu;
}

#[test]
fn two_robots_merge_into_the_all_points_map() {
    let codec = SummaryCodec {
        mean_bits: 8,
        psi_blocks: 8,
        mean_bits_growth: 0,
        lead: 0,
        lead_bits: 0,
        rice: false,
    };
    let r = run(
        codec,
        &[path(0.5, 7.0, 5.0, 0.2), path(4.0, 11.0, 8.0, -0.3)],
        64 * 1024,
    );
    let map = r.base.map().unwrap();
    assert_eq!(r.base.sessions().len(), 2);
    let shared = map
        .voxels()
        .filter(|(_, v)| {
            let robots: std::collections::BTreeSet<_> = v.closed.iter().map(|c| c.robot).collect();
            robots.len() == 2
        })
        .count();
    assert!(shared > 500, "only {shared} voxels seen by both robots");
    let (_, agree_w, lambda_w, mu_w) = compare(&r.world, map, &evicted_truth(&r.world, &r.robots));
    let (n, agree, worst_lambda, rms_mu) = compare(&r.world, map, &reference_truth(&r.reference));
    println!("two robots: {n} voxels, {shared} seen by both");
    println!("  vs evictions merged in f32: agreement {agree_w:.4}, worst Δλ/λ {lambda_w:.2e}, RMS ‖Δμ‖/‖μ‖ {mu_w:.4}");
    println!("  vs f32 reference:           agreement {agree:.4}, worst Δλ/λ {worst_lambda:.2e}, RMS ‖Δμ‖/‖μ‖ {rms_mu:.4}");
    assert!(
        lambda_w < 1e-5 && mu_w < 0.01 && agree_w >= 0.999,
        "merge is not exact"
    );
    assert!(worst_lambda < 1e-4);
    assert!(rms_mu < 0.05, "{rms_mu}");
    assert!(agree >= 0.99);
}

#[test]
fn codec_trade_off_table() {
    // Bytes vs agreement with the robot's own map, on the voxels one run evicts.
    let r = run(
        SummaryCodec::DEFAULT,
        &[path(0.5, 11.0, 3.0, 0.0)],
        64 * 1024,
    );
    let evicted = &r.robots[0].evicted;
    let (count, bytes) = summary_bytes(&r.base);
    let head = bytes as f64 / count as f64 - SummaryCodec::DEFAULT.code_len(D) as f64;
    // The robot's own map: its evicted statistics merged and gathered in f32.
    let truth = evicted_truth(&r.world, &r.robots);
    println!(
        "mean bits | psi blocks | bytes/summary | argmax agreement with the robot's map | RMS ‖Δμ‖/‖μ‖"
    );
    let mut previous = 0.0;
    for bits in 2..=6u8 {
        let codec = SummaryCodec {
            mean_bits: bits,
            psi_blocks: 8,
            mean_bits_growth: 0,
            lead: 0,
            lead_bits: 0,
            rice: false,
        };
        // What a base station gathers from the summaries at this codec.
        let mut received =
            host_sim::ObsMap::<D>::new(r.world.config.map_config().unwrap()).unwrap();
        for (k, _, st) in evicted {
            let mut codes = [0u8; 128];
            encode_codes(codec, st, &mut codes).unwrap();
            received.merge_observations(*k, &decode_codes::<D>(codec, st.count, &codes).unwrap());
        }
        let got = received.posteriors_sorted();
        assert_eq!(got.len(), truth.len());
        let (mut agree, mut sq) = (0usize, 0.0f64);
        for ((_, g), (_, t)) in got.iter().zip(&truth) {
            agree += usize::from(label(&r.world.vocab, &g.mean) == label(&r.world.vocab, &t.mean));
            let num: f32 = g
                .mean
                .iter()
                .zip(&t.mean)
                .map(|(a, b)| (a - b) * (a - b))
                .sum();
            let den: f32 = t.mean.iter().map(|x| x * x).sum();
            sq += f64::from(num / den.max(1e-12));
        }
        let agree = agree as f64 / truth.len() as f64;
        println!(
            "{bits} | 8 | {:.1} | {agree:.4} | {:.4}",
            head + codec.code_len(D) as f64,
            (sq / truth.len() as f64).sqrt()
        );
        assert!(agree + 0.005 >= previous, "more bits should not agree less");
        previous = agree;
    }
}
