//! Tests of [`super`] (apart, so that `scene.rs` stays one idea under 500 lines).

use super::*;
use latentbki::wire::{SessionConfig, Summary};
use latentbki::{obs::ObsStats, wire::SummaryCodec, MapConfig};

const D: usize = 4;

fn map() -> GlobalMap<D> {
    let codec = SummaryCodec {
        mean_bits: 8,
        psi_blocks: 4,
        mean_bits_growth: 0,
        lead: 0,
        lead_bits: 0,
        rice: false,
    };
    GlobalMap::new(SessionConfig::new(&MapConfig::default(), D, codec, 0)).unwrap()
}

fn observe(map: &mut GlobalMap<D>, robot: u16, key: VoxelKey, m: f32) {
    let obs = ObsStats {
        count: 5.0,
        mean: [m, 1.0 - m, 0.0, 0.0],
        scatter: [0.1; D],
    };
    let s = Summary {
        key,
        residency: 0,
        is_final: true,
        obs,
        at_ceiling: Default::default(),
        time: None,
    };
    map.apply(robot, 1, 0, &s);
}

fn vocab() -> Codebook<D, 4> {
    Codebook::from_embeddings(&[[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]]).unwrap()
}

#[test]
fn updates_carry_only_the_blocks_in_reach_and_full_scenes_everything() {
    let mut m = map();
    let (a, b, far) = (
        VoxelKey::new(0, 0, 0),
        VoxelKey::new(7, 0, 0),
        VoxelKey::new(40, 0, 0),
    );
    for (k, v) in [(a, 0.9), (b, 0.2), (far, 0.8)] {
        observe(&mut m, 1, k, v);
    }
    let cb = vocab();
    let mut scene = DecodedMap::<D, 4>::new(m.map_config().voxel_size());
    let all = m.sorted_keys();
    let dirty = scene.update(&m, &all, Some(&cb), None);
    assert_eq!(scene.len(), 3);
    assert_eq!(dirty.len(), 2, "a and b share a block");
    assert_eq!(scene.row(&a).unwrap().class.unwrap().0, 0);
    assert_eq!(scene.row(&b).unwrap().class.unwrap().0, 1);
    // A second robot observes `far`: only its block changes; `a`'s block is untouched.
    observe(&mut m, 2, far, 0.1);
    let keys = DecodedMap::<D, 4>::affected(&m, [far]);
    assert_eq!(keys, vec![far]);
    let dirty = scene.update(&m, &keys, Some(&cb), None);
    assert_eq!(
        dirty.into_iter().collect::<Vec<_>>(),
        vec![BlockKey::of(far)]
    );
    assert_eq!(scene.row(&far).unwrap().robots, vec![1, 2]);
    // Nothing changed: nothing to send.
    assert!(scene.update(&m, &keys, Some(&cb), None).is_empty());
    // The full scene deletes everything first, then holds every voxel once, values in metadata.
    let t = Timestamp::now();
    let full = scene.full_message(Layer::Classes, t);
    assert_eq!(full.deletions.len(), 1);
    let cubes: usize = full.entities.iter().map(|e| e.cubes.len()).sum();
    assert_eq!(cubes, 3);
    let e = scene.entity(Layer::Robots, BlockKey::of(far), t).unwrap();
    assert_eq!(e.metadata[0].value, "40 0 0");
    assert_eq!(e.metadata[1].value, "1+2");
    // A phrase scores every voxel; the heat layer's metadata carries the exact score.
    scene.set_query(Some(&cb));
    let h = scene.entity(Layer::Heat, BlockKey::of(a), t).unwrap();
    let scores: Vec<f32> = h.metadata[1]
        .value
        .split(',')
        .map(|s| s.parse().unwrap())
        .collect();
    assert_eq!(scores[0], scene.row(&a).unwrap().heat.unwrap());
    assert!(scores[0] > scores[1], "a matches category 0 better than b");
}

#[test]
fn joined_bytes_are_the_messages_and_follow_every_change() {
    use foxglove::Decode;
    let mut m = map();
    let (a, far) = (VoxelKey::new(0, 0, 0), VoxelKey::new(40, 0, 0));
    for (k, v) in [(a, 0.9), (far, 0.8)] {
        observe(&mut m, 1, k, v);
    }
    let cb = vocab();
    let mut scene = DecodedMap::<D, 4>::new(m.map_config().voxel_size());
    scene.update(&m, &m.sorted_keys(), Some(&cb), None);
    scene.fix_ranges();
    let t = Timestamp::new(1, 0);
    // First send builds every block; joining the cache again gives the same bytes.
    for layer in Layer::ALL {
        let built = encode(&scene.full_message(layer, t));
        assert_eq!(scene.full_bytes(layer, t), built);
        assert_eq!(scene.full_bytes(layer, t), built);
    }
    // `far` turns into class 1: its block is built again (at the new time), `a`'s block is kept.
    observe(&mut m, 2, far, 0.0);
    observe(&mut m, 2, far, 0.0);
    let dirty = scene.update(&m, &[far], Some(&cb), None);
    assert_eq!(scene.row(&far).unwrap().class.unwrap().0, 1);
    let t2 = Timestamp::new(2, 0);
    let upd = SceneUpdate::decode(&scene.update_bytes(Layer::Classes, &dirty, t2)[..]).unwrap();
    assert_eq!(upd, scene.update_message(Layer::Classes, &dirty, t2));
    let full =
        SceneUpdate::decode(&scene.full_bytes(Layer::Classes, Timestamp::new(3, 0))[..]).unwrap();
    assert_eq!(full.entities.len(), 2);
    assert_eq!(
        full.entities[0],
        scene.entity(Layer::Classes, BlockKey::of(a), t).unwrap()
    );
    assert_eq!(full.entities[1], upd.entities[0]);
    assert_eq!(full.entities[1].metadata[1].value, "1");
    // A phrase re-colours the heat layer: no stale bytes survive it.
    scene.set_query(Some(&cb));
    let heat = SceneUpdate::decode(&scene.full_bytes(Layer::Heat, t2)[..]).unwrap();
    assert_eq!(heat, scene.full_message(Layer::Heat, t2));
}

#[test]
fn the_centre_ignores_a_stray_voxel_and_classes_take_their_palette() {
    let mut m = map();
    for x in 0..40 {
        observe(&mut m, 1, VoxelKey::new(x, 10, 0), 0.9);
    }
    let stray = VoxelKey::new(4000, 10, 0);
    observe(&mut m, 1, stray, 0.9);
    let mut scene = DecodedMap::<D, 4>::new(m.map_config().voxel_size());
    assert_eq!(scene.centre(), None);
    scene.update(&m, &m.sorted_keys(), Some(&vocab()), None);
    let v = m.map_config().voxel_size();
    let c = scene.centre().unwrap();
    // x: 5th to 95th percentile of 0..=39 and the stray, i.e. keys 2 and 38 (+1 for the far side).
    assert!((c[0] - 20.5 * v).abs() < 0.6 * v, "{c:?}");
    assert!((c[1] - 10.5 * v).abs() < 1e-4, "{c:?}");
    scene.set_palette(vec![[1, 2, 3], [4, 5, 6]]);
    assert_eq!(scene.class_colour(1), [4, 5, 6]);
    assert_eq!(scene.class_colour(7), crate::export::label_colour(7));
    let e = scene
        .entity(
            Layer::Classes,
            BlockKey::of(VoxelKey::new(0, 10, 0)),
            Timestamp::new(1, 0),
        )
        .unwrap();
    let c = e.cubes[0].color.as_ref().unwrap();
    assert_eq!(
        [c.r, c.g, c.b].map(|x| (x * 255.0).round() as u8),
        [1, 2, 3]
    );
    assert_eq!(scene.class_counts(2), vec![41, 0]);
}

#[test]
fn the_heat_cloud_holds_every_voxel_with_the_heat_layers_colour_and_score() {
    let mut m = map();
    for (x, v) in [(0, 0.9), (9, 0.1), (30, 0.5)] {
        observe(&mut m, 1, VoxelKey::new(x, 0, 0), v);
    }
    let cb = vocab();
    let mut scene = DecodedMap::<D, 4>::new(m.map_config().voxel_size());
    scene.update(&m, &m.sorted_keys(), Some(&cb), None);
    let cloud = crate::view::cloud::heat_cloud(&scene, Timestamp::new(1, 0));
    assert_eq!(cloud.data.len(), 3 * cloud.point_stride as usize);
    // Without a query: NaN scores, the undefined grey.
    assert!(f32::from_le_bytes(cloud.data[16..20].try_into().unwrap()).is_nan());
    assert_eq!(&cloud.data[12..16], &[128, 128, 128, 255]);
    scene.set_query(Some(&cb));
    let cloud = crate::view::cloud::heat_cloud(&scene, Timestamp::new(2, 0));
    let stride = cloud.point_stride as usize;
    for ((k, row), p) in scene.voxels().zip(cloud.data.chunks_exact(stride)) {
        let f = |o: usize| f32::from_le_bytes(p[o..o + 4].try_into().unwrap());
        assert_eq!([f(0), f(4), f(8)], k.centroid(scene.voxel_size()));
        assert_eq!(&p[12..15], &scene.colour(Layer::Heat, row));
        assert_eq!(f(16), row.heat.unwrap());
    }
}
