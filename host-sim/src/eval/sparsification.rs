//! Sparsification curves and AUSE: does the map's uncertainty point at its errors? (paper Fig. 4)
//!
//! Held-out points are sorted by the uncertainty of the voxel they fall in; the most uncertain fraction is
//! removed step by step and accuracy / mIoU are computed on the rest. A useful uncertainty makes the curve
//! rise. The **oracle** removes the wrong points first (the best any ranking can do); AUSE (area under the
//! sparsification error, Ilg et al. 2018) is the area between the oracle's curve and the method's, in
//! accuracy (or mIoU) points, averaged over the removed fractions: 0 is perfect, larger is worse. A random
//! ranking is shown for reference (its expected curve is flat).

use super::metrics::Confusion;

/// One evaluated point with its uncertainties (all of its voxel; λ > 2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScoredPoint {
    /// True class.
    pub truth: u16,
    /// Predicted class.
    pub predicted: u16,
    /// E-optimality, the authors' convention (max of t_var = (λ+1)/λ²·Ψ).
    pub e_opt: f32,
    /// D-optimality, the authors' convention (geometric mean of t_var).
    pub d_opt: f32,
    /// E-optimality of the Student-t covariance (λ+1)/(λ(λ−2))·Ψ.
    pub e_opt_cov: f32,
    /// D-optimality of the Student-t covariance.
    pub d_opt_cov: f32,
    /// Sampling uncertainty by the authors' procedure (variance of the predicted class's score).
    pub sampling: f32,
    /// Sampling uncertainty of the model's predictive (multivariate t, cosine score).
    pub sampling_sound: f32,
    /// A uniform random number (for the random-ranking baseline).
    pub random: f32,
}

/// A ranking: its name and its key (larger = more uncertain).
pub type Ranking = (&'static str, fn(&ScoredPoint) -> f32);

/// The rankings of the analysis, in table order.
pub const RANKINGS: [Ranking; 7] = [
    ("E-optimality (authors' t_var)", |p| p.e_opt),
    ("D-optimality (authors' t_var)", |p| p.d_opt),
    ("E-optimality (Student-t covariance)", |p| p.e_opt_cov),
    ("D-optimality (Student-t covariance)", |p| p.d_opt_cov),
    ("sampling (authors' procedure)", |p| p.sampling),
    ("sampling (multivariate t, cosine)", |p| p.sampling_sound),
    ("random", |p| p.random),
];

/// One sparsification curve.
#[derive(Clone, Debug, PartialEq)]
pub struct Curve {
    /// Name of the ranking.
    pub name: String,
    /// Fractions removed.
    pub removed: Vec<f64>,
    /// Accuracy of the rest at each fraction.
    pub accuracy: Vec<f64>,
    /// mIoU of the rest at each fraction.
    pub miou: Vec<f64>,
}

/// Fractions removed: 0, 5 %, …, 90 %.
pub fn default_fractions() -> Vec<f64> {
    (0..=18).map(|i| f64::from(i) * 0.05).collect()
}

/// The curve for a ranking: `order` lists point indices from the most to the least uncertain.
pub fn curve(
    name: &str,
    points: &[ScoredPoint],
    order: &[usize],
    classes: usize,
    fractions: &[f64],
) -> Curve {
    let mut accuracy = Vec::with_capacity(fractions.len());
    let mut miou = Vec::with_capacity(fractions.len());
    for &f in fractions {
        let skip = ((points.len() as f64) * f).round() as usize;
        let mut c = Confusion::new(classes);
        for &i in &order[skip.min(order.len())..] {
            let p = &points[i];
            c.add(usize::from(p.truth), Some(usize::from(p.predicted)));
        }
        accuracy.push(c.accuracy());
        miou.push(c.miou());
    }
    Curve {
        name: name.to_string(),
        removed: fractions.to_vec(),
        accuracy,
        miou,
    }
}

/// Indices sorted by descending key (ties by index, so the order is deterministic).
pub fn rank_by(points: &[ScoredPoint], key: impl Fn(&ScoredPoint) -> f32) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..points.len()).collect();
    idx.sort_by(|&a, &b| key(&points[b]).total_cmp(&key(&points[a])).then(a.cmp(&b)));
    idx
}

/// The oracle ranking: wrong points first.
pub fn oracle_order(points: &[ScoredPoint]) -> Vec<usize> {
    rank_by(points, |p| if p.truth != p.predicted { 1.0 } else { 0.0 })
}

/// Area between the oracle's and a curve's values, averaged over the fractions (trapezoids).
pub fn ause(oracle: &[f64], method: &[f64], fractions: &[f64]) -> f64 {
    if fractions.len() < 2 {
        return 0.0;
    }
    let gap: Vec<f64> = oracle.iter().zip(method).map(|(o, m)| o - m).collect();
    let mut area = 0.0;
    for i in 1..fractions.len() {
        area += (gap[i] + gap[i - 1]) / 2.0 * (fractions[i] - fractions[i - 1]);
    }
    area / (fractions[fractions.len() - 1] - fractions[0])
}

/// All curves of the paper's figure: E-opt, D-opt (both conventions), sampling (both modes), and the
/// oracle and random references.
#[derive(Clone, Debug)]
pub struct Sparsification {
    /// Curves in [`RANKINGS`] order, then the oracle.
    pub curves: Vec<Curve>,
    /// AUSE (accuracy, mIoU) per ranking curve except the oracle, same order.
    pub ause: Vec<(String, f64, f64)>,
    /// Points evaluated.
    pub points: usize,
}

/// Compute every curve and AUSE.
pub fn analyse(points: &[ScoredPoint], classes: usize) -> Sparsification {
    let fr = default_fractions();
    let oracle = curve("oracle", points, &oracle_order(points), classes, &fr);
    let mut curves: Vec<Curve> = RANKINGS
        .iter()
        .map(|(name, key)| curve(name, points, &rank_by(points, key), classes, &fr))
        .collect();
    let ause = curves
        .iter()
        .map(|c| {
            (
                c.name.clone(),
                ause(&oracle.accuracy, &c.accuracy, &fr),
                ause(&oracle.miou, &c.miou, &fr),
            )
        })
        .collect();
    curves.push(oracle);
    Sparsification {
        curves,
        ause,
        points: points.len(),
    }
}
