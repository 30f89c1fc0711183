//! The scale chosen by validation never sees the test: every held-out point scrambled (class, feature,
//! position), the choice and every candidate's score are bit-identical; the integrated points' classes
//! scrambled, the scores change (so this test can fail). And the split is of the integrated points only,
//! disjoint, a fifth of them.

use host_sim::eval::experiment::{self, ExperimentSettings};
use host_sim::eval::methods::EncodedFrame;
use host_sim::eval::scale_search::{self, Candidate, Choice};
use host_sim::eval::scenes::{SceneKind, SceneOptions, SceneSource};
use host_sim::sim::vocab::TextEmbeddings;
use latentbki::MapConfig;

fn frames() -> (Vec<EncodedFrame>, experiment::Decoding, ExperimentSettings) {
    let options = SceneOptions {
        tile_frames: 6,
        tile_points: 1500,
        ..SceneOptions::default()
    };
    let setup = ExperimentSettings::default();
    let source = SceneSource::new(SceneKind::Tile, &options, setup.seed).unwrap();
    let (train, test) = source.train_and_test().unwrap();
    let dec = experiment::decoding(&TextEmbeddings::builtin(), &train, &setup).unwrap();
    let frames = experiment::encode(&test, &dec, &setup);
    (frames, dec, setup)
}

fn choose(
    frames: &[EncodedFrame],
    dec: &experiment::Decoding,
    setup: &ExperimentSettings,
) -> Choice {
    let candidates: Vec<Candidate> = [(0.1, 0.1), (0.1, 0.3), (0.2, 0.4)]
        .iter()
        .map(|&(voxel, kernel)| Candidate {
            voxel,
            kernel,
            filter: 3,
        })
        .collect();
    scale_search::choose_uncached(
        frames,
        &candidates,
        &MapConfig::default(),
        &dec.decoder,
        dec.classes.len(),
        setup,
        &|_| true,
    )
    .unwrap()
}

#[test]
fn held_out_points_never_reach_the_choice() {
    let (frames, dec, setup) = frames();
    let before = choose(&frames, &dec, &setup);
    let k = dec.classes.len() as u16;
    let mut scrambled = frames.clone();
    for (t, f) in scrambled.iter_mut().enumerate() {
        for (i, c) in f.held_classes.iter_mut().enumerate() {
            *c = (*c + 1 + (i as u16 % (k - 1))) % k;
        }
        for y in &mut f.held_features {
            y.iter_mut().for_each(|v| *v = -*v + t as f32);
        }
        for p in &mut f.held_points {
            p[0] += 0.37;
            p[2] -= 1.0;
        }
        // The test's held-out set itself changes size: half of it dropped.
        let keep = f.held_points.len() / 2;
        f.held_points.truncate(keep);
        f.held_classes.truncate(keep);
        f.held_features.truncate(keep);
    }
    let after = choose(&scrambled, &dec, &setup);
    assert_eq!(before.best, after.best);
    assert_eq!(
        before.scored, after.scored,
        "a held-out point reached the scores"
    );
    assert_eq!(before.config, after.config);

    // The integrated points' classes do reach it: shifted, every score moves.
    let mut relabelled = frames.clone();
    for f in &mut relabelled {
        for c in &mut f.classes {
            *c = (*c + 1) % k;
        }
    }
    let moved = choose(&relabelled, &dec, &setup);
    for (a, b) in before.scored.iter().zip(&moved.scored) {
        assert_ne!(a.accuracy, b.accuracy, "{:?}", a.candidate);
    }
}

#[test]
fn the_split_is_a_fifth_of_the_integrated_points_and_disjoint() {
    let (frames, _, setup) = frames();
    let split = scale_search::split(&frames, setup.seed);
    let (mut fit, mut val, mut integrated) = (0, 0, 0);
    for (f, s) in frames.iter().zip(&split) {
        integrated += f.points.len();
        fit += s.fit.points.len();
        val += s.points.len();
        assert!(s.fit.held_points.is_empty());
        // Every fit and validation point is one of the frame's integrated points, none twice.
        let mut all: Vec<[u32; 3]> = s
            .fit
            .map_points
            .iter()
            .chain(&s.points)
            .map(|p| p.map(f32::to_bits))
            .collect();
        let mut want: Vec<[u32; 3]> = f.map_points.iter().map(|p| p.map(f32::to_bits)).collect();
        all.sort_unstable();
        want.sort_unstable();
        assert_eq!(all, want);
    }
    assert_eq!(fit + val, integrated);
    let share = val as f64 / integrated as f64;
    assert!((share - 0.2).abs() < 0.02, "{share}");
}
