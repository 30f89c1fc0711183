//! The `query` command: map one scene with the device map, then show where a free-text query matches
//! (a heat map) and which voxels match best. Apart from `eval` and `demo` ([`super`]) because it is the
//! one command that decodes a map with a user's phrase instead of scoring it against ground truth.

use super::eval::{QueryArgs, SceneArg};
use crate::cli_args::TileArgs;
use crate::eval::experiment::{self, ExperimentSettings, Method};
use crate::eval::figures::{self, TopDown};
use crate::eval::methods::Decoder;
use crate::eval::scenes::{SceneKind, SceneOptions, SceneSource};
use crate::sim::vocab::TextEmbeddings;
use anyhow::{bail, ensure, Context, Result};

/// `query`: map a scene with the device map and show where the text matches.
pub fn query(args: &QueryArgs) -> Result<()> {
    let scene = match args.scene {
        SceneArg::Tile => SceneKind::Tile,
        SceneArg::Indoor => SceneKind::Indoor,
        SceneArg::Both | SceneArg::Changing => {
            bail!("query maps one scene: give --scene tile or --scene indoor")
        }
    };
    // The output folder first: finding it unusable after the mapping would waste the run.
    let dir = args.out.join(scene.name());
    std::fs::create_dir_all(&dir)
        .with_context(|| format!("--out: cannot create the folder {}", dir.display()))?;
    let vocab = TextEmbeddings::builtin();
    let embedding = match vocab.get(&args.text) {
        Ok(e) => *e,
        // Built with the `encoder` feature, any text works: embed it now.
        #[cfg(feature = "encoder")]
        Err(_) => crate::text_encoder::embed(&[args.text.as_str()])?[0],
        #[cfg(not(feature = "encoder"))]
        Err(e) => {
            return Err(anyhow::anyhow!(
                "{e} (build with `--features encoder` to query any text)"
            ))
        }
    };
    ensure!(
        scene == SceneKind::Tile || args.tile == TileArgs::default(),
        "--las, --units, --range and --altitude describe the tile scene; --scene indoor does not use them"
    );
    ensure!(
        scene == SceneKind::Tile || args.map.config()? == latentbki::MapConfig::default(),
        "the map options (--voxel-size …) apply to the tile scene; --scene indoor uses the paper's indoor configuration"
    );
    let options = SceneOptions {
        tile: args.tile.clone(),
        tile_config: args.map.config()?,
        tile_map: args.tile.las.as_ref().map(|_| args.map.clone()),
        ..SceneOptions::default()
    };
    let source = SceneSource::new(scene, &options, args.seed)?;
    let (train, test) = source.train_and_test()?;
    let setup = ExperimentSettings {
        seed: args.seed,
        device_window: source.device_window(&test.config),
        ..ExperimentSettings::default()
    };
    let dec = experiment::decoding(&vocab, &train, &setup)?;
    let frames = experiment::encode(&test, &dec, &setup);
    let results = crate::eval::runner::run(
        &[Method::OnDevice(test.config.filter_size())],
        &experiment::Inputs {
            frames: &frames,
            config: &test.config,
            dec: &dec,
            setup: &setup,
        },
        None,
        None,
        "mapping",
    )?;
    let snap = results[0].mapper.snapshot();
    let top = TopDown::new(&snap, &test.config, test.cutaway_height);
    let cb = Decoder::from_pca(&dec.pca, &[embedding]).map_err(|e| anyhow::anyhow!("{e}"))?;
    // Where does the query beat every class name? (open vocabulary: the query competes with the classes)
    let mut with_query = (0..dec.classes.len())
        .map(|c| *dec.encoder.embedding(c as u16))
        .collect::<Vec<_>>();
    with_query.push(embedding);
    let all = Decoder::from_pca(&dec.pca, &with_query).map_err(|e| anyhow::anyhow!("{e}"))?;
    let q_index = with_query.len() - 1;
    let mut ranked: Vec<(f32, [f32; 3], usize)> = snap
        .iter()
        .filter(|(_, v)| v.lambda >= 1.0)
        .map(|(k, v)| {
            let best = all.argmax(&v.mean).map_or(0, |(c, _)| c);
            (
                cb.score(&v.mean, 0),
                k.centroid(test.config.voxel_size()),
                best,
            )
        })
        .collect();
    let won = ranked.iter().filter(|r| r.2 == q_index).count();
    ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
    println!(
        "\"{}\" in the {} map ({} voxels): it is the best match among the scene's classes and the query in {} voxels ({:.1} %).",
        args.text,
        scene.name(),
        ranked.len(),
        won,
        100.0 * won as f64 / ranked.len().max(1) as f64
    );
    println!("best-matching voxels (cosine, position in m, nearest class name):");
    for (s, p, best) in ranked.iter().take(5) {
        let nearest = dec
            .decoder
            .argmax(
                &snap
                    .iter()
                    .find(|(k, _)| k.centroid(test.config.voxel_size()) == *p)
                    .map(|(_, v)| v.mean)
                    .unwrap_or([0.0; 64]),
            )
            .map_or("?", |(c, _)| dec.classes[c].as_str());
        let tag = if *best == q_index {
            " (query wins)"
        } else {
            ""
        };
        println!(
            "  {s:.3}  ({:.1}, {:.1}, {:.1})  {nearest}{tag}",
            p[0], p[1], p[2]
        );
    }
    let path = dir.join(format!("query_{}.png", args.text.trim().replace(' ', "_")));
    figures::query_heatmap(&path, &args.text, &top, &test.config, &cb)
        .map_err(|e| anyhow::anyhow!("drawing: {e}"))?;
    println!("wrote {}", path.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cli_args::MapArgs;
    use std::path::Path;

    fn query_args(out: &Path, scene: SceneArg) -> QueryArgs {
        QueryArgs {
            text: "road".into(),
            scene,
            out: out.to_owned(),
            seed: 7,
            tile: TileArgs::default(),
            map: MapArgs::default(),
        }
    }

    #[test]
    fn query_refuses_both_scenes() {
        let dir = tempfile::tempdir().unwrap();
        let err = query(&query_args(dir.path(), SceneArg::Both)).unwrap_err();
        assert!(
            err.to_string().contains("--scene tile or --scene indoor"),
            "{err}"
        );
    }

    #[test]
    fn query_checks_its_output_folder_before_mapping() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a-file");
        std::fs::write(&file, b"").unwrap();
        // A point cloud that does not exist: had the scene been loaded (and mapped) before the output
        // folder was checked, the error would name this file instead of --out.
        let mut args = query_args(&file, SceneArg::Tile);
        args.tile.las = Some(dir.path().join("missing.las"));
        let err = query(&args).unwrap_err();
        let msg = format!("{err:#}");
        assert!(
            msg.contains("--out")
                && msg.contains(&file.display().to_string())
                && !msg.contains("missing.las"),
            "{msg}"
        );
    }
}
