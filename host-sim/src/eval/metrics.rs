//! Accuracy and mean IoU from a confusion matrix, with an explicit "unknown" prediction.
//!
//! A held-out point whose voxel the map never observed gets no prediction. It is counted as **wrong** (a
//! false negative of its true class, a false positive of no class): a map that leaves holes should not look
//! better than one that fills them. mIoU averages the IoU over the classes present in the ground truth of
//! the evaluated points (classes never present have an undefined IoU and are left out, as usual).

/// A K × (K + 1) confusion matrix: rows are true classes, columns predicted classes, the last column
/// "unknown" (no prediction).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Confusion {
    k: usize,
    counts: Vec<u64>,
}

impl Confusion {
    /// An empty matrix for `k` classes.
    pub fn new(k: usize) -> Self {
        Self {
            k,
            counts: vec![0; k * (k + 1)],
        }
    }

    /// Number of classes.
    pub fn classes(&self) -> usize {
        self.k
    }

    /// Record one point: its true class and the prediction (`None` = unknown).
    pub fn add(&mut self, truth: usize, predicted: Option<usize>) {
        let col = predicted.filter(|&p| p < self.k).unwrap_or(self.k);
        self.counts[truth * (self.k + 1) + col] += 1;
    }

    /// Add another matrix of the same size.
    pub fn merge(&mut self, other: &Self) {
        assert_eq!(self.k, other.k, "confusion matrices of different sizes");
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
    }

    /// Count of (true, predicted) with `None` = unknown.
    pub fn get(&self, truth: usize, predicted: Option<usize>) -> u64 {
        self.counts[truth * (self.k + 1) + predicted.unwrap_or(self.k)]
    }

    /// Points recorded.
    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// Points with no prediction.
    pub fn unknown(&self) -> u64 {
        (0..self.k).map(|t| self.get(t, None)).sum()
    }

    /// Correct predictions / all points (unknown counts as wrong); 0 for an empty matrix.
    pub fn accuracy(&self) -> f64 {
        let total = self.total();
        if total == 0 {
            return 0.0;
        }
        let correct: u64 = (0..self.k).map(|c| self.get(c, Some(c))).sum();
        correct as f64 / total as f64
    }

    /// IoU of one class, TP / (TP + FP + FN); `None` if the class is absent from the ground truth.
    pub fn iou(&self, c: usize) -> Option<f64> {
        let row: u64 = (0..=self.k)
            .map(|p| self.counts[c * (self.k + 1) + p])
            .sum();
        if row == 0 {
            return None;
        }
        let tp = self.get(c, Some(c));
        let fp: u64 = (0..self.k)
            .filter(|&t| t != c)
            .map(|t| self.get(t, Some(c)))
            .sum();
        let fn_ = row - tp;
        Some(tp as f64 / (tp + fp + fn_) as f64)
    }

    /// Mean IoU as the authors' evaluation averages it (`generate_results.py`: `union += 1e-6`, then every
    /// class with union > 0 — that is, all of them): a class absent from both truth and prediction counts
    /// 0, a class only predicted counts 0. 0 for no classes.
    pub fn miou_authors(&self) -> f64 {
        if self.k == 0 {
            return 0.0;
        }
        let sum: f64 = (0..self.k)
            .map(|c| {
                let tp = self.get(c, Some(c)) as f64;
                let row: u64 = (0..=self.k)
                    .map(|p| self.counts[c * (self.k + 1) + p])
                    .sum();
                let col: u64 = (0..self.k).map(|t| self.get(t, Some(c))).sum();
                tp / ((row + col) as f64 - tp + 1e-6)
            })
            .sum();
        sum / self.k as f64
    }

    /// Mean IoU over classes present in the ground truth; 0 if there are none.
    pub fn miou(&self) -> f64 {
        let ious: Vec<f64> = (0..self.k).filter_map(|c| self.iou(c)).collect();
        if ious.is_empty() {
            0.0
        } else {
            ious.iter().sum::<f64>() / ious.len() as f64
        }
    }
}
