//! The base station's map answers queries and draws itself (PNG top-down views, PLY). Its storage is tested
//! in `stream_db.rs`.

mod stream_common;

use host_sim::base_station::export::{
    heat_image, label_image, uncertainty_image, write_ply, write_pngs,
};
use host_sim::base_station::{BaseStation, GlobalMap};
use host_sim::link::SplitMix;
use latentbki::wire::SummaryCodec;
use stream_common::*;

/// A small two-pass run of one robot, streamed and received.
fn small_map() -> (World, GlobalMap<D>) {
    let world = World::new(SummaryCodec::DEFAULT);
    let mut robot = RobotRig::new(&world, 3, 2.5);
    let mut rng = SplitMix::new(9);
    let mut x = 1.0;
    while x < 7.0 {
        let (pose, pts, feats) = scan(&world, &mut rng, x, 1.0, 400, 1.6);
        robot.step(&pose, &pts, &feats, 4096);
        x += 0.5;
    }
    // Leave some voxels live (not flushed): the file must keep open contributions too.
    robot.tick(1 << 20);
    let mut base = BaseStation::<D>::new(world.config).unwrap();
    base.receive(&robot.uart.0);
    let map = base.into_map().unwrap();
    assert!(
        map.voxels().any(|(_, v)| !v.live.is_empty()),
        "some contributions are still live"
    );
    (world, map)
}

#[test]
fn queries_and_exports_show_the_scene() {
    let (world, map) = small_map();
    // Labels: voxels on the road are labelled road, on the building building (the scene's ground truth).
    let mut right = 0;
    let mut total = 0;
    let voxel = map.map_config().voxel_size();
    for k in map.sorted_keys() {
        let c = k.centroid(voxel);
        let truth = class_at(c[0], c[1]);
        // Only voxels well inside one class region and well observed.
        let inside = [-0.2f32, 0.2].iter().all(|dx| {
            [-0.2f32, 0.2]
                .iter()
                .all(|dy| class_at(c[0] + dx, c[1] + dy) == truth)
        });
        if !inside || map.posterior(&k).unwrap().lambda < 5.0 {
            continue;
        }
        total += 1;
        right += usize::from(map.label(&k, &world.vocab).unwrap().0 == truth);
    }
    assert!(
        total > 200 && right as f64 / total as f64 > 0.95,
        "{right}/{total}"
    );
    // Heat of the "building" query is higher on the building than on the road.
    let mean_heat = |class: usize| {
        let v: Vec<f32> = map
            .sorted_keys()
            .iter()
            .filter(|k| {
                let c = k.centroid(voxel);
                class_at(c[0], c[1]) == class
            })
            .map(|k| map.heat(k, &world.vocab, BUILDING).unwrap())
            .collect();
        v.iter().sum::<f32>() / v.len() as f32
    };
    assert!(mean_heat(BUILDING) > mean_heat(ROAD) + 0.05);
    // Uncertainty: well-observed voxels have a D-optimality; it falls as λ grows.
    let mut pairs: Vec<(f32, f32)> = map
        .posteriors()
        .iter()
        .filter_map(|(k, p)| Some((p.lambda, map.uncertainty(k)?.d_optimality?)))
        .collect();
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let q = pairs.len() / 4;
    let low: f32 = pairs[..q].iter().map(|p| p.1).sum::<f32>() / q as f32;
    let high: f32 = pairs[pairs.len() - q..].iter().map(|p| p.1).sum::<f32>() / q as f32;
    assert!(
        high < low,
        "more observations, less uncertainty: {high} vs {low}"
    );

    // Images: one pixel per column, road colour along the road's centre line.
    let img = label_image(&map, &world.vocab, 1).unwrap();
    let keys = map.sorted_keys();
    let (x0, y1) = (
        keys.iter().map(|k| k.x).min().unwrap(),
        keys.iter().map(|k| k.y).max().unwrap(),
    );
    let px = |x: f32, y: f32| {
        let (kx, ky) = ((x / voxel).floor() as i32, (y / voxel).floor() as i32);
        img.get_pixel((kx - x0) as u32, (y1 - ky) as u32)
    };
    let road = host_sim::base_station::export::label_colour(ROAD);
    assert_eq!(px(4.0, 0.05), road, "{:?}", {
        let k = latentbki::key::VoxelKey::new(40, 0, 0);
        (
            map.label(&k, &world.vocab),
            map.observations(&k).map(|o| o.count),
        )
    });
    assert_eq!(
        px(4.0, 2.0),
        host_sim::base_station::export::label_colour(BUILDING)
    );
    let heat = heat_image(&map, &world.vocab, BUILDING, 2).unwrap();
    assert_eq!(heat.width(), img.width() * 2);
    uncertainty_image(&map, 1).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let files = write_pngs(
        &map,
        &world.vocab,
        Some((&world.vocab, BUILDING)),
        &dir.path().join("map"),
        3,
    )
    .unwrap();
    assert_eq!(files.len(), 4);
    assert!(files[3].ends_with("map-gain.png"));
    for f in &files {
        let back = host_sim::png_io::RgbImage::read_png(f).unwrap();
        assert_eq!(back.width(), img.width() * 3);
    }
    let ply = dir.path().join("map.ply");
    write_ply(&map, &world.vocab, &ply).unwrap();
    let text = std::fs::read_to_string(&ply).unwrap();
    assert!(text.starts_with("ply\nformat ascii 1.0\n"));
    // Every voxel the map answers (within the kernel's reach of an observation).
    let answered = map.posteriors().len();
    assert!(answered > map.len());
    assert!(text.contains(&format!("element vertex {answered}\n")));
    assert_eq!(
        text.lines().skip_while(|l| *l != "end_header").count() - 1,
        answered
    );
}
