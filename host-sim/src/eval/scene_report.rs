//! One scene's experiment end to end: its sequences, the decoding, every method's run (and the sparsity
//! sweep), the tables, the sparsification analysis and the pictures, gathered in a [`Report`]. Apart from
//! [`super::scenes`], which says *what* is mapped (the scene, its sensor and map scale); this is *how* an
//! evaluation of it runs.

use super::experiment::{self, ExperimentSettings, Method, MethodResult};
use super::figures::{self, TopDown};
use super::methods::{Decoder, Radio};
use super::runner;
use super::scenes::{tile_query, SceneKind, SceneOptions, SceneSource};
use super::sparsification::{self, Sparsification};
use super::sweep::{Sweep, SweepPoint};
use crate::sim::vocab::TextEmbeddings;
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// Everything one scene's experiment produced.
pub struct Report {
    /// Scene.
    pub scene: SceneKind,
    /// Method results, in table order.
    pub results: Vec<MethodResult>,
    /// Sparsification of the LatentBKI f = 3 map's uncertainty.
    pub sparsification: Sparsification,
    /// The sparsity sweep (empty if not run).
    pub sweep: Vec<SweepPoint>,
    /// The Markdown section for this scene.
    pub markdown: String,
    /// PNGs written.
    pub figures: Vec<PathBuf>,
    /// One line saying what to change when the map left most held-out points unknown.
    pub hint: Option<String>,
}

/// Run one scene's experiment and write its pictures into `out/<scene>/`.
pub fn run(
    scene: SceneKind,
    options: &SceneOptions,
    setup: &ExperimentSettings,
    out: &Path,
    sweep: bool,
    link: Option<Box<dyn Radio>>,
) -> Result<Report> {
    let vocab = TextEmbeddings::builtin();
    let mut source = SceneSource::new(scene, options, setup.seed)?;
    let (train, test) = source.train_and_test()?;
    let dec = experiment::decoding(&vocab, &train, setup)?;
    let frames = experiment::encode(&test, &dec, setup);
    // The scale: given, or chosen now by validation on the integrated points (never the held-out ones).
    let (chosen, choice) = source.resolve_config(&frames, &dec, setup)?;
    // Without a choice, the sequence's own configuration (indoors the paper's 0.05 m).
    let config = if choice.is_some() {
        chosen
    } else {
        test.config
    };
    if choice.is_some() {
        println!(
            "map scale: {} (candidates in the table below)",
            source.scale_note()
        );
    }
    let setup = &ExperimentSettings {
        device_window: source.device_window(&config),
        ..*setup
    };
    let f = config.filter_size();
    let device_refusal = source.device_refusal(&config);
    let methods: Vec<Method> = Method::for_filter(f)
        .into_iter()
        .filter(|m| {
            device_refusal.is_none() || !matches!(m, Method::OnDevice(_) | Method::OnDeviceInt8(_))
        })
        .collect();
    let budgets = match scene {
        SceneKind::Tile => &options.sweep_tile,
        SceneKind::Indoor => &options.sweep_indoor,
    };
    let sweep = if sweep && !budgets.is_empty() {
        Sweep::new(
            &|b| {
                let mut seq = source.sequence(b, false);
                seq.config = config;
                seq
            },
            budgets,
            &options.sweep_filters,
            &dec,
            setup,
        )
    } else {
        Sweep::none()
    };
    let (results, sweep_points) = runner::run_with_sweep(
        &methods,
        &experiment::Inputs {
            frames: &frames,
            config: &config,
            dec: &dec,
            setup,
        },
        Some(Method::LatentBki(f)),
        link,
        &sweep,
        &format!("{}: methods and sweep", scene.name()),
    )?;
    drop(sweep);
    let scored = &results
        .iter()
        .find(|r| r.method == Method::LatentBki(f))
        .expect("LatentBKI ran at the scene's filter size")
        .scored;
    let spars = sparsification::analyse(scored, dec.classes.len());

    // Pictures, from the on-device map (what the robot holds plus what it streamed).
    let dir = out.join(scene.name());
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let device = results
        .iter()
        .find(|r| matches!(r.method, Method::OnDevice(_)))
        .or_else(|| results.iter().find(|r| r.method == Method::LatentBki(f)))
        .expect("a LatentBKI map ran");
    let snap = device.mapper.snapshot();
    let top = TopDown::new(&snap, &config, test.cutaway_height);
    let which = device.method.label();
    let mut figs = Vec::new();
    let fig = |e: Box<dyn std::error::Error + Send + Sync>| anyhow::anyhow!("drawing: {e}");
    let p = dir.join("semantic_map.png");
    figures::semantic_map(
        &p,
        &format!("{}: top-down semantic map ({which})", scene.name()),
        &top,
        &config,
        &dec.decoder,
        &dec.classes,
    )
    .map_err(fig)?;
    figs.push(p);
    let queries: Vec<String> = if options.queries.is_empty() {
        match scene {
            SceneKind::Tile => tile_query(&dec.classes, &vocab).into_iter().collect(),
            SceneKind::Indoor => vec![scene.default_query().to_string()],
        }
    } else {
        options.queries.clone()
    };
    for q in &queries {
        let cb =
            Decoder::from_pca(&dec.pca, &[*vocab.get(q)?]).map_err(|e| anyhow::anyhow!("{e}"))?;
        let p = dir.join(format!("query_{}.png", q.replace(' ', "_")));
        figures::query_heatmap(&p, q, &top, &config, &cb).map_err(fig)?;
        figs.push(p);
    }
    let p = dir.join("uncertainty_eopt.png");
    figures::uncertainty_map(
        &p,
        &format!("{}: E-optimality, authors' t_var ({which})", scene.name()),
        &top,
        &config,
    )
    .map_err(fig)?;
    figs.push(p);
    let p = dir.join("sparsification.png");
    figures::sparsification_plot(&p, scene.name(), &spars).map_err(fig)?;
    figs.push(p);
    if !sweep_points.is_empty() {
        let p = dir.join("sparsity_sweep.png");
        figures::sweep_plot(&p, scene.name(), &sweep_points).map_err(fig)?;
        figs.push(p);
    }

    let held: usize = frames.iter().map(|f| f.held_points.len()).sum();
    let integrated: usize = frames.iter().map(|f| f.points.len()).sum();
    let notes = format!(
        "{} frames, {:.0} points per frame ({} integrated, {} held out); PCA 384 → 64 fitted on another sequence keeps {:.1} % of the variance; {}. Unknown = held-out points whose voxel the map had not observed (counted wrong).",
        frames.len(),
        test.points() as f64 / test.frames.len().max(1) as f64,
        integrated,
        held,
        100.0 * dec.explained_variance,
        if source.scale_note().is_empty() {
            format!(
                "voxel {} m, ℓ = {} m",
                config.voxel_size(),
                config.kernel_length()
            )
        } else {
            format!("map scale: {}", source.scale_note())
        },
    );
    let mut md = String::new();
    if let Some(c) = &choice {
        md += &format!("{}\n", c.table());
    }
    md += &super::tables::results_table(&format!("Scene: {}", source.title()), &results, &notes);
    if let Some(why) = &device_refusal {
        md += &format!("\nThe on-device rows did not run at this scale: {why}.\n");
    }
    if let Some(r) = results.iter().find(|r| r.method == Method::LatentBki(f)) {
        md += &format!(
            "\nmIoU above averages the classes present in the ground truth ({} of {}); averaged as the authors' evaluation does (all {} classes, an absent class counting 0), LatentBKI f32 (f = {f}) has {:.2} %.\n",
            (0..r.confusion.classes()).filter(|&c| r.confusion.iou(c).is_some()).count(),
            r.confusion.classes(),
            r.confusion.classes(),
            100.0 * r.confusion.miou_authors()
        );
    }
    for r in &results {
        if let Some(note) = r
            .mapper
            .refused()
            .and_then(|c| refusal_note(&r.method.label(), &c, integrated))
        {
            md += &note;
        }
    }
    md += &super::tables::iou_table(&dec.classes, &results);
    md += &format!(
        "\nUncertainty of LatentBKI (f = {f}) vs error, {} held-out points with λ > 2 — AUSE (lower is better; accuracy / mIoU points). Sampling: {} draws, variance of the predicted class's score:\n\n| Uncertainty | AUSE acc. | AUSE mIoU |\n|---|---:|---:|\n",
        spars.points, setup.sampling_draws
    );
    for (name, a, m) in &spars.ause {
        md += &format!("| {name} | {:.2} | {:.2} |\n", 100.0 * a, 100.0 * m);
    }
    if !sweep_points.is_empty() {
        md += "\nSparsity sweep (LatentBKI f32): accuracy / mIoU (%) by points per frame\n\n| points/frame |";
        let filters = &options.sweep_filters;
        for f in filters {
            md += &format!(" f = {f} |");
        }
        md += "\n|---:|";
        md += &"---:|".repeat(filters.len());
        md += "\n";
        for &b in budgets {
            let row: Vec<&SweepPoint> = sweep_points.iter().filter(|p| p.budget == b).collect();
            if let Some(first) = row.first() {
                md += &format!("| {:.0} |", first.points_per_frame);
                for p in &row {
                    md += &format!(" {:.2} / {:.2} |", 100.0 * p.accuracy, 100.0 * p.miou);
                }
                md += "\n";
            }
        }
    }
    let hint = source.coverage_hint(&results, f, &config);
    Ok(Report {
        scene,
        results,
        sparsification: spars,
        sweep: sweep_points,
        markdown: md,
        figures: figs,
        hint,
    })
}

/// One line for a method whose map refused points: how many, why, and what lowers the load. `None` when it
/// took every point.
fn refusal_note(label: &str, c: &latentbki::RejectionCounts, handed: usize) -> Option<String> {
    if c.total() == 0 {
        return None;
    }
    let reasons: Vec<String> = [
        (c.no_room, "no room"),
        (c.outside_window, "outside its window"),
        (c.non_finite_position, "non-finite position"),
        (c.non_finite_feature, "non-finite feature"),
        (c.key_out_of_range, "beyond the key range"),
        (c.unpaired, "unpaired"),
        (c.code_out_of_range, "int8 code −128"),
        (c.feature_scale, "no int8 scale"),
    ]
    .iter()
    .filter(|(n, _)| *n > 0)
    .map(|(n, why)| format!("{why} {n}"))
    .collect();
    let advice = if c.no_room > 0 {
        format!(
            " No room: its map ({} voxels) was full and a frame's evictions overflowed its link queue \
             ({} KiB between ticks) — back-pressure, nothing dropped silently; fewer --points per frame or \
             a coarser --voxel-size lower the load.",
            super::methods::DEVICE_CAPACITY,
            super::methods::DEVICE_QUEUE / 1024
        )
    } else {
        String::new()
    };
    Some(format!(
        "\n{label}: the robot's map refused {} of the {handed} points handed to it ({}), each counted; its \
         row covers only the points it took.{advice}\n",
        c.total(),
        reasons.join(", ")
    ))
}

#[cfg(test)]
mod tests {
    use super::refusal_note;
    use latentbki::RejectionCounts;

    #[test]
    fn a_map_that_took_every_point_gets_no_note() {
        assert_eq!(refusal_note("m", &RejectionCounts::default(), 10), None);
    }

    #[test]
    fn refusals_are_counted_by_reason_and_no_room_says_what_lowers_the_load() {
        let c = RejectionCounts {
            no_room: 5,
            outside_window: 2,
            ..RejectionCounts::default()
        };
        let note = refusal_note("robot", &c, 100).unwrap();
        assert!(note.contains("refused 7 of the 100 points"), "{note}");
        assert!(note.contains("no room 5, outside its window 2"), "{note}");
        assert!(note.contains("--points"), "{note}");
        let c = RejectionCounts {
            outside_window: 3,
            ..RejectionCounts::default()
        };
        let note = refusal_note("robot", &c, 100).unwrap();
        assert!(!note.contains("No room"), "{note}");
    }
}
