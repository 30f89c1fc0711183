//! `host-sim feature-space`: fit a robot's feature space ([`crate::feature_space`]) and write the files
//! the base station and the firmware take.

use crate::feature_space::FeatureSpace;
use anyhow::{bail, Result};
use std::path::PathBuf;

/// `host-sim feature-space`.
#[derive(clap::Args, Debug)]
pub struct FeatureSpaceArgs {
    /// The robot's classes, comma separated, in the order of its segmenter's scores (words of the committed
    /// vocabulary; any text with the `encoder` feature).
    #[arg(long, value_delimiter = ',', required = true)]
    pub classes: Vec<String>,
    /// Folder to write pca.npz, feature_space.rs and vocabulary.tsv into (created if missing).
    #[arg(long)]
    pub out: PathBuf,
}

/// Run `host-sim feature-space`.
pub fn run(args: &FeatureSpaceArgs) -> Result<()> {
    let space = FeatureSpace::new(&args.classes)?;
    let files = space.write(&args.out)?;
    println!("feature space id: {:#010x}", space.id);
    let trip = space.round_trip();
    let worst = trip.iter().map(|t| t.0).fold(1.0f32, f32::min);
    let all_right = trip.iter().enumerate().all(|(k, t)| t.1 == k);
    println!(
        "classes: {} ({}); int8 scale {:.6} (code c = {:.6} · c); each class's int8 prototype decodes {} (cosine with its embedding ≥ {worst:.4})",
        space.classes.join(", "),
        space.classes.len(),
        space.scale,
        space.scale,
        if all_right { "to itself" } else { "WRONGLY for some class" },
    );
    println!(
        "wrote {} (base station: map-query DB --pca {} --classes {})",
        files[0].display(),
        files[0].display(),
        space.classes.join(",")
    );
    println!(
        "wrote {} (firmware: `mod feature_space;`, Setup::with_classes(&PROTOTYPES), PROTOTYPES.mix(&scores, &mut codes) per point; docs/firmware.md)",
        files[1].display()
    );
    println!(
        "wrote {} (the classes' text embeddings: the base station reads it beside --pca)",
        files[2].display()
    );
    if !all_right {
        bail!("some class's prototype decodes to another class: the classes are too alike to tell apart");
    }
    Ok(())
}
