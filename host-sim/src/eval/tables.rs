//! The experiment's Markdown tables, apart from the runs that fill them: the results table (one row per
//! method) and the per-class IoU (classes as rows and methods as columns: the mIoU column of the main
//! table averages these, and on a user's tile this shows where the map's smoothing helps (large classes)
//! and where it costs (small ones)).

use super::experiment::MethodResult;

/// The Markdown table: one row per class with its held-out points, one column per method; "–" where the
/// class is absent from the held-out ground truth.
pub fn iou_table(classes: &[String], results: &[MethodResult]) -> String {
    let mut s =
        String::from("\nPer-class IoU (%) on the held-out points:\n\n| Class | Held-out points |");
    for r in results {
        s += &format!(" {} |", r.method.label());
    }
    s += "\n|---|---:|";
    s += &"---:|".repeat(results.len());
    s += "\n";
    for (c, name) in classes.iter().enumerate() {
        let support: u64 = results.first().map_or(0, |r| {
            (0..r.confusion.classes())
                .map(|p| r.confusion.get(c, Some(p)))
                .sum::<u64>()
                + r.confusion.get(c, None)
        });
        s += &format!("| {name} | {support} |");
        for r in results {
            match r.confusion.iou(c) {
                Some(iou) => s += &format!(" {:.2} |", 100.0 * iou),
                None => s += " – |",
            }
        }
        s += "\n";
    }
    s
}

/// The results table in Markdown.
pub fn results_table(scene: &str, results: &[MethodResult], notes: &str) -> String {
    let mut s = format!("### {scene}\n\n{notes}\n\n| Method | Acc. (%) | mIoU (%) | Unknown (%) | Acc. where observed (%) | Voxels | Uncertainty |\n|---|---:|---:|---:|---:|---:|---|\n");
    for r in results {
        let total = r.confusion.total().max(1) as f64;
        s += &format!(
            "| {} | {:.2} | {:.2} | {:.2} | {:.2} | {} | {} |\n",
            r.method.label(),
            100.0 * r.confusion.accuracy(),
            100.0 * r.confusion.miou(),
            100.0 * r.confusion.unknown() as f64 / total,
            100.0 * r.confusion.accuracy() * total
                / (total - r.confusion.unknown() as f64).max(1.0),
            if r.voxels == 0 {
                "–".to_string()
            } else {
                r.voxels.to_string()
            },
            if r.method.has_uncertainty() {
                "yes"
            } else {
                "no"
            },
        );
    }
    s
}
