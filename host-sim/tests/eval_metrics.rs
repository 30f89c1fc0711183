//! Metric computations against hand-made cases: confusion matrix → accuracy, IoU, mIoU (with unknown
//! predictions), and sparsification / AUSE on toy rankings.

use host_sim::eval::metrics::Confusion;
use host_sim::eval::sparsification::{analyse, ause, curve, oracle_order, rank_by, ScoredPoint};

/// 3 classes. Truth / prediction pairs:
/// class 0: 4 points → 3 right, 1 predicted as 1
/// class 1: 3 points → 1 right, 1 predicted as 2, 1 unknown
/// class 2: 0 points (absent from the ground truth), but predicted once (above)
#[test]
fn confusion_to_accuracy_iou_miou() {
    let mut c = Confusion::new(3);
    for (t, p) in [
        (0, Some(0)),
        (0, Some(0)),
        (0, Some(0)),
        (0, Some(1)),
        (1, Some(1)),
        (1, Some(2)),
        (1, None),
    ] {
        c.add(t, p);
    }
    assert_eq!(c.total(), 7);
    assert_eq!(c.unknown(), 1);
    assert!((c.accuracy() - 4.0 / 7.0).abs() < 1e-12);
    // Class 0: TP 3, FP 0, FN 1 → 3/4.
    assert!((c.iou(0).unwrap() - 0.75).abs() < 1e-12);
    // Class 1: TP 1, FP 1 (a class-0 point), FN 2 (one wrong, one unknown) → 1/4.
    assert!((c.iou(1).unwrap() - 0.25).abs() < 1e-12);
    // Class 2 never occurs in the truth: no IoU, not averaged.
    assert_eq!(c.iou(2), None);
    assert!((c.miou() - 0.5).abs() < 1e-12);
    // The authors' average counts class 2 (only predicted) as 0: (3/4 + 1/4 + 0) / 3.
    assert!((c.miou_authors() - 1.0 / 3.0).abs() < 1e-6);
    // With every class present the two agree (up to the authors' 1e-6 in the union).
    let mut full = Confusion::new(2);
    for (t, p) in [(0, Some(0)), (0, Some(1)), (1, Some(1))] {
        full.add(t, p);
    }
    assert!((full.miou_authors() - full.miou()).abs() < 1e-6);

    // Merging adds counts.
    let mut d = Confusion::new(3);
    d.add(2, Some(2));
    d.merge(&c);
    assert_eq!(d.total(), 8);
    assert_eq!(d.iou(2), Some(0.5), "TP 1, FP 1 (the class-1 point)");

    // Empty matrix: zero, not NaN.
    assert_eq!(Confusion::new(2).accuracy(), 0.0);
    assert_eq!(Confusion::new(2).miou(), 0.0);
}

fn pt(truth: u16, predicted: u16, u: f32) -> ScoredPoint {
    ScoredPoint {
        truth,
        predicted,
        e_opt: u,
        d_opt: -u, // the reverse ranking
        e_opt_cov: u,
        d_opt_cov: -u,
        sampling: 0.0,
        sampling_sound: 0.0,
        random: 0.0,
    }
}

/// 10 points, 2 wrong; the E-opt ranking puts both wrong points first (a perfect uncertainty), the D-opt
/// ranking puts them last.
#[test]
fn sparsification_and_ause_on_a_toy_case() {
    let mut pts: Vec<ScoredPoint> = (0..8).map(|i| pt(0, 0, i as f32)).collect();
    pts.push(pt(1, 0, 100.0));
    pts.push(pt(0, 1, 99.0));
    let fr = [0.0, 0.1, 0.2, 0.5];
    let perfect = curve("e", &pts, &rank_by(&pts, |p| p.e_opt), 2, &fr);
    assert_eq!(perfect.accuracy, vec![0.8, 8.0 / 9.0, 1.0, 1.0]);
    let oracle = curve("o", &pts, &oracle_order(&pts), 2, &fr);
    assert_eq!(oracle.accuracy, perfect.accuracy);
    assert_eq!(ause(&oracle.accuracy, &perfect.accuracy, &fr), 0.0);

    let worst = curve("d", &pts, &rank_by(&pts, |p| p.d_opt), 2, &fr);
    // Removing the most certain (correct) points first: 8/10, 7/9, 6/8, 3/5.
    let expect = [0.8, 7.0 / 9.0, 0.75, 0.6];
    for (a, b) in worst.accuracy.iter().zip(expect) {
        assert!((a - b).abs() < 1e-12);
    }
    // AUSE by hand: gaps 0, 1/9, 1/4, 2/5 over widths 0.1, 0.1, 0.3, normalised by 0.5.
    let by_hand =
        ((0.0 + 1.0 / 9.0) / 2.0 * 0.1 + (1.0 / 9.0 + 0.25) / 2.0 * 0.1 + (0.25 + 0.4) / 2.0 * 0.3)
            / 0.5;
    assert!((ause(&oracle.accuracy, &worst.accuracy, &fr) - by_hand).abs() < 1e-12);

    let s = analyse(&pts, 2);
    assert_eq!(s.points, 10);
    let e = s
        .ause
        .iter()
        .find(|a| a.0 == "E-optimality (authors' t_var)")
        .unwrap();
    let d = s
        .ause
        .iter()
        .find(|a| a.0 == "D-optimality (authors' t_var)")
        .unwrap();
    assert!(e.1 < 1e-12 && d.1 > 0.1, "E {e:?} D {d:?}");
}
