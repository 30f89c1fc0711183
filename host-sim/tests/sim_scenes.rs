//! The simulator's scenes and encoder: the real tile is read in metres with the right classes, the house is
//! seeded, and the encoder errs the way its documentation says.

use host_sim::sim::encoder::{Encoder, NoiseModel};
use host_sim::sim::indoor::{self, IndoorRun, IndoorScene, INDOOR_CLASSES};
use host_sim::sim::tile::{self, Tile, TileRun};
use host_sim::sim::vocab::{cosine, TextEmbeddings, FULL_DIM};
use host_sim::sim::{pca, LabelledPoint};
use rand_xoshiro::rand_core::SeedableRng;
use rand_xoshiro::Xoshiro256PlusPlus;

#[test]
fn tile_is_read_in_metres_with_its_classes() {
    let t = Tile::builtin().unwrap();
    assert_eq!(t.points.len(), 25_408);
    let (lo, hi) = t.bounds;
    // data/README.md: 18.28 × 12.19 × 15.62 m (59.99 × 39.98 × 51.26 US survey ft).
    let ext = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
    for (e, want) in ext.iter().zip([18.28f32, 12.19, 15.62]) {
        assert!((e - want).abs() < 0.01, "extent {ext:?}");
    }
    assert!(
        lo.iter().all(|v| v.abs() < 1e-3),
        "local origin at the minimum corner"
    );
    let mut hist = [0usize; 6];
    for &c in &t.classes {
        hist[usize::from(c)] += 1;
    }
    assert_eq!(hist, [9808, 158, 724, 10956, 3737, 25]);
    // Every class phrase is in the vocabulary.
    let vocab = TextEmbeddings::builtin();
    for n in t.class_names() {
        vocab.get(&n).unwrap();
    }
}

#[test]
fn tile_sequence_is_seeded_and_within_range() {
    let t = Tile::builtin().unwrap();
    let run = TileRun {
        frames: 4,
        ..TileRun::default()
    };
    let a = tile::sequence(&t, &run);
    let b = tile::sequence(&t, &run);
    assert_eq!(a.frames.len(), 4);
    for (fa, fb) in a.frames.iter().zip(&b.frames) {
        assert_eq!(fa.points, fb.points);
        assert_eq!(fa.points.len(), run.lidar.points_per_frame);
        let s = fa.pose.translation.vector;
        for p in &fa.points {
            let d = ((p.position[0] - s.x).powi(2)
                + (p.position[1] - s.y).powi(2)
                + (p.position[2] - s.z).powi(2))
            .sqrt();
            assert!(d < run.lidar.range_m + 0.2);
        }
    }
    let c = tile::sequence(&t, &TileRun { seed: 2, ..run });
    assert_ne!(a.frames[0].points, c.frames[0].points);
}

#[test]
fn indoor_camera_sees_the_house() {
    let house = IndoorScene::generate(1);
    let seq = indoor::sequence(&house, &IndoorRun::default());
    assert!(seq.frames.len() > 40, "{} frames", seq.frames.len());
    let mut seen = vec![0usize; INDOOR_CLASSES.len()];
    for f in &seq.frames {
        let cam = f.pose.translation.vector;
        for p in &f.points {
            seen[usize::from(p.class)] += 1;
            let r = ((p.position[0] - cam.x).powi(2) + (p.position[1] - cam.y).powi(2)).sqrt();
            assert!(r < 6.0 * 1.5, "depth limit (6 m along the optical axis)");
            assert!(
                p.position[2] > house.floor - 0.01
                    && p.position[2] < house.floor + house.height + 0.01,
                "{p:?} from {cam:?}"
            );
        }
    }
    for c in ["wall", "floor", "door", "table", "chair"] {
        let i = INDOOR_CLASSES.iter().position(|n| *n == c).unwrap();
        assert!(seen[i] > 0, "{c} never seen");
    }
}

fn encoder(model: NoiseModel) -> (Encoder, Vec<[f32; FULL_DIM]>) {
    let vocab = TextEmbeddings::builtin();
    let names = Tile::builtin().unwrap().class_names();
    let names: Vec<&str> = names.iter().map(String::as_str).collect();
    let emb = vocab.embeddings(&names).unwrap();
    (Encoder::new(emb.clone(), model, 9), emb)
}

fn grid_points(n: usize, class: u16) -> Vec<LabelledPoint> {
    (0..n)
        .map(|i| LabelledPoint {
            position: [(i % 100) as f32 * 2.0, (i / 100) as f32 * 2.0, 0.0],
            class,
            instance: 1,
        })
        .collect()
}

#[test]
fn clean_encoder_returns_the_text_embedding() {
    let (enc, emb) = encoder(NoiseModel {
        confusion_probability: 0.0,
        feature_noise: 0.0,
        ..NoiseModel::default()
    });
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(1);
    let f = enc.encode_full(&grid_points(10, 4), 0, &mut rng);
    assert!(f.iter().all(|y| *y == emb[4]));
}

#[test]
fn confusions_are_per_segment_persistent_and_semantic() {
    let model = NoiseModel::default();
    let (enc, emb) = encoder(model);
    // 2000 points on a 2 m grid: each point its own segment (cells are 1.5 m).
    let pts = grid_points(2000, 1); // "low vegetation"
    let frames = 30u32;
    let mut wrong = 0usize;
    let mut to_similar = 0usize;
    let mut changes = 0usize;
    for p in &pts {
        let mut prev = None;
        for t in 0..frames {
            let c = enc.perceived_class(p, t);
            if c != p.class {
                wrong += 1;
                if c == 2 || c == 3 {
                    to_similar += 1; // medium / high vegetation
                }
            }
            if prev.is_some_and(|q| q != c) {
                changes += 1;
            }
            prev = Some(c);
        }
    }
    let rate = wrong as f64 / (pts.len() * frames as usize) as f64;
    assert!((rate - 0.25).abs() < 0.02, "confusion rate {rate}");
    // Vegetation is confused with vegetation far more than with ground/building/noise.
    let sim = |a: usize, b: usize| cosine(&emb[a], &emb[b]);
    assert!(sim(1, 2) > sim(1, 5));
    assert!(
        to_similar as f64 / wrong as f64 > 0.5,
        "{to_similar}/{wrong}"
    );
    // Persistence: decisions last blocks of 3 frames, so the label changes at most at block edges.
    let max_changes = pts.len() * (frames as usize / 3 + 1);
    assert!(changes <= max_changes);
    assert!(changes < pts.len() * frames as usize / 2);
    // All points of one segment share the decision in a frame.
    let seg: Vec<LabelledPoint> = (0..50)
        .map(|i| LabelledPoint {
            position: [0.1 + i as f32 * 0.02, 0.2, 0.3],
            class: 1,
            instance: 1,
        })
        .collect();
    for t in 0..frames {
        let first = enc.perceived_class(&seg[0], t);
        assert!(seg.iter().all(|p| enc.perceived_class(p, t) == first));
    }
}

#[test]
fn compressed_encoding_matches_projecting_full_features() {
    let (enc, _) = encoder(NoiseModel::default());
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(5);
    let pts: Vec<LabelledPoint> = (0..6u16)
        .flat_map(|c| {
            (0..400).map(move |i| LabelledPoint {
                position: [i as f32 * 2.0, f32::from(c) * 50.0, 0.0],
                class: c,
                instance: u32::from(c),
            })
        })
        .collect();
    // Fit on one sample, compare on another (a PCA's own training sample overstates its variances).
    let p = pca::fit::<16>(&enc.encode_full(&pts, 1, &mut rng)).unwrap();
    let full = enc.encode_full(&pts, 0, &mut rng);
    let projected = enc.project_classes(&p);
    let a: Vec<[f32; 16]> = full.iter().map(|y| p.project(y)).collect();
    let b = enc.encode_compressed(&pts, 0, &projected, &mut rng);
    // Same distribution: per-dimension means and variances agree.
    for d in 0..16 {
        let stats = |v: &[[f32; 16]]| {
            let m = v.iter().map(|x| f64::from(x[d])).sum::<f64>() / v.len() as f64;
            let s = v.iter().map(|x| (f64::from(x[d]) - m).powi(2)).sum::<f64>() / v.len() as f64;
            (m, s)
        };
        let (ma, sa) = stats(&a);
        let (mb, sb) = stats(&b);
        assert!((ma - mb).abs() < 0.02, "dim {d}: mean {ma} vs {mb}");
        assert!((sa / sb - 1.0).abs() < 0.15, "dim {d}: var {sa} vs {sb}");
    }
}

#[test]
fn pca_finds_the_subspace_and_is_orthonormal() {
    // Points in a 3-d subspace of R^384 plus tiny noise: 3 components keep almost all the variance.
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(2);
    use rand::Rng;
    let basis: Vec<[f32; FULL_DIM]> = (0..3)
        .map(|k| {
            std::array::from_fn(|i| {
                if i % 3 == k {
                    1.0 / (128f32).sqrt()
                } else {
                    0.0
                }
            })
        })
        .collect();
    let samples: Vec<[f32; FULL_DIM]> = (0..500)
        .map(|_| {
            let w: [f32; 3] = [
                rng.random_range(-3.0..3.0),
                rng.random_range(-2.0..2.0),
                rng.random_range(-1.0..1.0),
            ];
            std::array::from_fn(|i| {
                w[0] * basis[0][i]
                    + w[1] * basis[1][i]
                    + w[2] * basis[2][i]
                    + 1.0
                    + rng.random_range(-1e-3..1e-3)
            })
        })
        .collect();
    let p = pca::fit::<3>(&samples).unwrap();
    assert!(p.orthonormality_error() < 1e-4);
    assert!(pca::explained_variance(&p, &samples) > 0.999);
    // The first component is the widest direction.
    assert!(cosine(&p.components[0], &basis[0]).abs() > 0.99);
    assert!(pca::fit::<8>(&samples[..5]).is_err());
}

#[test]
fn unknown_words_list_the_vocabulary() {
    let v = TextEmbeddings::builtin();
    assert_eq!(v.phrases().len(), 64);
    let e = v.get("spaceship").unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("spaceship")
            && msg.contains("high vegetation")
            && msg.contains("a place to sleep")
    );
    assert!(v.get("  Tree ").is_ok());
}
