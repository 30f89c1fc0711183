//! `host-sim map-info` and `host-sim map-query`: a map database read, also while a base station writes
//! it — its summary, or its labels, a query and the PNG/PLY/MCAP exports.

use super::*;

/// Run `host-sim map-info`.
pub fn map_info(args: &MapInfoArgs) -> Result<()> {
    let mut store = SqliteStore::open_read_only(&args.db)?;
    let snapshot = store.snapshot()?;
    let committed = snapshot.committed_at_ms;
    let base =
        BaseStation::<D>::restore(snapshot).with_context(|| args.db.display().to_string())?;
    say!(
        "{}: map database schema {SCHEMA_VERSION}, voxel record {}, last commit {}",
        args.db.display(),
        crate::base_station::global_map::VOXEL_RECORD_VERSION,
        if committed == 0 {
            "never".to_string()
        } else {
            format!("at unix time {:.3} s", committed as f64 / 1000.0)
        }
    );
    let Some(map) = base.map() else {
        say!("no session configuration yet: empty");
        return Ok(());
    };
    let c = map.config();
    say!(
        "configuration: D = {}, voxel {} m, kernel length {} m, filter size {}, sub-voxel cells {}, prior λ₀ {} μ₀ {} Ψ₀ {}, codec {}-bit μ / {} Ψ blocks, feature space {:#010x}",
        c.dim, c.voxel_size, c.kernel_length, c.filter_size, c.subvoxel_cells, c.prior_lambda,
        c.prior_mean, c.prior_psi, c.codec.mean_bits, c.codec.psi_blocks, c.feature_space
    );
    let (live, closed) = map.voxels().fold((0usize, 0usize), |(l, c), (_, v)| {
        (l + v.live.len(), c + v.closed.len())
    });
    say!(
        "observed voxels {}; contributions closed {closed}, live {live}; points Σn = {:.0}",
        map.len(),
        map.observed_points()
    );
    let size = |suffix: &str| {
        let mut p = args.db.clone().into_os_string();
        p.push(suffix);
        std::fs::metadata(p).map_or(0, |m| m.len())
    };
    say!(
        "file {:.1} MiB (+ write-ahead log {:.1} MiB)",
        size("") as f64 / (1 << 20) as f64,
        size("-wal") as f64 / (1 << 20) as f64
    );
    print_sessions(&base);
    Ok(())
}

/// Run `host-sim map-query`.
pub fn map_query(args: &MapQueryArgs) -> Result<()> {
    check_outputs(&args.out)?;
    if let Some(p) = &args.mcap {
        check_output("--mcap", p, false)?;
    }
    let (vocab, query) = read_vocabulary(&args.out)?;
    let base = read_map(&args.db)?;
    let Some(map) = base.map() else {
        bail!(
            "{}: no session configuration yet: the map is empty",
            args.db.display()
        );
    };
    say!("{}: {} voxels", args.db.display(), map.len());
    if let Some(path) = &args.mcap {
        let view = ViewArgs {
            view: None,
            record: Some(path.clone()),
            view_hz: 1000.0,
            view_backlog: 1,
        };
        let v = Viewer::start(view_options(
            &view,
            vocab.as_ref(),
            args.out.query.as_deref(),
        ))?;
        v.push_map(map);
        let r = v.finish().recording.unwrap_or_default();
        say!(
            "wrote {}: {} voxels in the scene, {} messages, {} bytes ({} on disk)",
            path.display(),
            r.voxels,
            r.messages,
            r.bytes,
            r.file_bytes
        );
    }
    show(map, &args.out, vocab.as_ref(), query.as_ref(), args.top)
}
