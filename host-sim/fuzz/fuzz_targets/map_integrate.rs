//! Arbitrary points and features (NaN, infinities, huge coordinates included) into the on-device map's
//! batch integration, with window moves and a sink that sometimes refuses: never a panic, every point
//! integrated or counted, every held voxel finite.
#![no_main]

use latentbki::nalgebra::{Isometry3, Translation3};
use latentbki::{local_map::LocalMap, packed_len, sink::Evicted, sink::SinkFull, MapConfig};
use libfuzzer_sys::fuzz_target;

const D: usize = 4;
const CAP: usize = 512;
type Map = LocalMap<D, CAP, { packed_len(D) }>;

fuzz_target!(|data: &[u8]| {
    let mut map = Box::new(Map::EMPTY);
    map.configure(MapConfig::default(), 1.0).unwrap();
    let f = |c: &[u8]| f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
    let mut refuse = false;
    let mut sink = |_v: Evicted<'_, D>| {
        refuse = !refuse;
        if refuse {
            Err(SinkFull)
        } else {
            Ok(())
        }
    };
    let record = 4 * (3 + D);
    for batch in data.chunks(record * 16 + 12) {
        if batch.len() < 12 {
            break;
        }
        let t = [f(&batch[0..]), f(&batch[4..]), f(&batch[8..])];
        let pose = Isometry3::from_parts(Translation3::new(t[0], t[1], t[2]), Default::default());
        let mut pts = Vec::new();
        let mut feats = Vec::new();
        for c in batch[12..].chunks_exact(record) {
            pts.push([f(c), f(&c[4..]), f(&c[8..])]);
            feats.push(core::array::from_fn(|d| f(&c[12 + 4 * d..])));
        }
        let before = map.rejections().total();
        let n = map.integrate(&pose, &pts, &feats, &mut sink);
        assert_eq!(n + (map.rejections().total() - before) as usize, pts.len());
    }
    assert!(map.iter().all(|v| v.obs.is_valid()));
});
