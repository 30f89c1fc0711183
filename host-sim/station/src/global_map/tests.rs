//! The exact merge, its records and its lookups.

use super::*;
use latentbki::wire::SummaryCodec;

const D: usize = 4;

fn map() -> GlobalMap<D> {
    let c = SessionConfig::new(
        &MapConfig::default(),
        D,
        SummaryCodec {
            mean_bits: 8,
            psi_blocks: 4,
            mean_bits_growth: 0,
            lead: 0,
            lead_bits: 0,
            rice: false,
        },
        0,
    );
    GlobalMap::new(c).unwrap()
}

fn summary(residency: u32, is_final: bool, count: f32, m: f32) -> Summary<D> {
    Summary {
        key: VoxelKey::new(1, 2, 3),
        residency,
        is_final,
        obs: ObsStats {
            count,
            mean: [m; D],
            scatter: [1.0 + count; D],
        },
        at_ceiling: Default::default(),
        time: None,
    }
}

#[test]
fn voxel_records_round_trip_and_refuse_damage() {
    let mut g = map();
    g.apply(1, 1, 10, &summary(5, false, 1.0, 0.1));
    g.apply(1, 1, 11, &summary(6, true, 2.0, 0.3));
    g.apply(2, 7, 3, &summary(9, true, 1.5, -0.2));
    let v = g.voxel(&VoxelKey::new(1, 2, 3)).unwrap();
    let rec = v.to_record();
    assert_eq!(GlobalVoxel::<D>::from_record(&rec, None).unwrap(), *v);
    for cut in 0..rec.len() {
        assert!(
            GlobalVoxel::<D>::from_record(&rec[..cut], None).is_err(),
            "cut {cut}"
        );
    }
    let mut longer = rec.clone();
    longer.push(0);
    assert!(GlobalVoxel::<D>::from_record(&longer, None).is_err());
    let mut other = rec.clone();
    other[0] = VOXEL_RECORD_VERSION + 1;
    assert_eq!(
        GlobalVoxel::<D>::from_record(&other, None),
        Err(RecordError::Version(VOXEL_RECORD_VERSION + 1))
    );
    // The first part's n: version, base flag, closed count and two ids, parts count, the part's id.
    let mut nan = rec.clone();
    let at = 1 + 1 + 4 + 2 * 10 + 4 + 10;
    assert_eq!(nan[at..at + 4], 2.0f32.to_le_bytes());
    nan[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    assert_eq!(
        GlobalVoxel::<D>::from_record(&nan, None),
        Err(RecordError::NotFinite)
    );
    // A record of another dimension is refused, not misread.
    assert!(GlobalVoxel::<8>::from_record(&rec, None).is_err());
}

#[test]
fn replace_live_merge_finals_ignore_copies() {
    let mut g = map();
    let k = VoxelKey::new(1, 2, 3);
    assert_eq!(
        g.apply(1, 1, 10, &summary(5, false, 1.0, 0.1)),
        Applied::Updated
    );
    assert_eq!(
        g.apply(1, 1, 12, &summary(5, false, 2.0, 0.2)),
        Applied::Updated
    );
    assert_eq!(
        g.apply(1, 1, 11, &summary(5, false, 1.5, 0.3)),
        Applied::Stale
    );
    assert_eq!(
        g.observations(&k).unwrap().count,
        2.0,
        "live copies replace, never add"
    );
    assert_eq!(
        g.apply(1, 1, 13, &summary(5, true, 3.0, 0.2)),
        Applied::Merged
    );
    assert_eq!(
        g.observations(&k).unwrap().count,
        3.0,
        "the final closes the live one"
    );
    assert_eq!(
        g.apply(1, 1, 14, &summary(5, true, 3.0, 0.2)),
        Applied::DuplicateFinal
    );
    assert_eq!(
        g.apply(1, 1, 9, &summary(5, false, 1.0, 0.2)),
        Applied::Stale
    );
    // Another residency, another session, another robot: disjoint, merged.
    g.apply(1, 1, 20, &summary(6, true, 1.0, 0.5));
    g.apply(1, 2, 0, &summary(5, true, 1.0, 0.5));
    g.apply(2, 1, 0, &summary(5, false, 2.0, 0.5));
    let o = g.observations(&k).unwrap();
    assert_eq!(o.count, 3.0 + 1.0 + 1.0 + 2.0);
    let want = (3.0 * 0.2 + 4.0 * 0.5) / 7.0;
    assert!((o.mean[0] - want).abs() < 1e-6);
    assert!((g.observed_points() - 7.0).abs() < 1e-6);
    // The posterior of the voxel itself (λ₀ = 0): its own 7 points plus nothing else in reach.
    let p = g.posterior(&k).unwrap();
    assert_eq!(p.lambda, 7.0);
    assert!((p.mean[0] - want).abs() < 1e-6);
    // A neighbour sees it through the kernel; a far voxel sees nothing.
    let n = g.posterior(&VoxelKey::new(2, 2, 3)).unwrap();
    assert!((n.lambda - 7.0 * 0.7671).abs() < 1e-3);
    assert!(g.posterior(&VoxelKey::new(9, 9, 9)).is_none());
}

/// Live contributions arriving in any order merge to the same bits, and the lookups (kept in step
/// with every summary) equal the core's gather over [`GlobalMap::observations`] exactly.
#[test]
fn lookups_equal_the_core_gather_whatever_the_arrival_order() {
    let k = VoxelKey::new(1, 2, 3);
    let parts = [
        (3u16, 4u32, 0.7f32),
        (1, 9, -0.3),
        (2, 2, 0.11),
        (1, 1, 0.5),
    ];
    let mut forward = map();
    let mut backward = map();
    for (robot, residency, m) in parts {
        forward.apply(robot, 1, 0, &summary(residency, false, 1.0 + m.abs(), m));
    }
    for (robot, residency, m) in parts.iter().rev().copied() {
        backward.apply(robot, 1, 0, &summary(residency, false, 1.0 + m.abs(), m));
    }
    let (a, b) = (
        forward.observations(&k).unwrap(),
        backward.observations(&k).unwrap(),
    );
    assert_eq!(a.mean.map(f32::to_bits), b.mean.map(f32::to_bits));
    assert_eq!(a.scatter.map(f32::to_bits), b.scatter.map(f32::to_bits));
    assert_eq!(forward, backward);
    // A live copy replaced and one closed: the cached merge follows.
    forward.apply(1, 1, 1, &summary(9, false, 4.0, 0.25));
    forward.apply(2, 1, 1, &summary(2, true, 2.0, 0.125));
    struct Literal<'a>(&'a GlobalMap<D>);
    impl ObsLookup<D> for Literal<'_> {
        fn observed(&self, key: VoxelKey) -> Option<ObsStats<D>> {
            self.0.observations(&key)
        }
    }
    let lut: latentbki::kernel::KernelLut =
        latentbki::kernel::KernelLut::new(forward.map_config()).unwrap();
    let all = forward.posteriors();
    assert_eq!(all.len(), 27, "one voxel reaches its 3×3×3 neighbours");
    for (key, p) in &all {
        let want = latentbki::obs::gather(&lut, &Literal(&forward), *key)
            .unwrap()
            .posterior(&forward.prior());
        assert_eq!(forward.posterior(key).as_ref(), Some(&want), "{key:?}");
        assert_eq!(p.mean.map(f32::to_bits), want.mean.map(f32::to_bits));
        assert_eq!(p.lambda.to_bits(), want.lambda.to_bits());
    }
}

/// Final summaries settle to the same bits in any arrival order (the fold goes in id order), and the
/// record is the same bytes.
#[test]
fn finals_settle_to_the_same_bits_in_any_order() {
    let finals = [
        (1u16, 1u32, 6u32, 2.0f32, 0.3f32),
        (2, 7, 9, 1.5, -0.2),
        (1, 1, 2, 7.0, 0.11),
        (3, 1, 1, 3.0, 0.9),
    ];
    let k = VoxelKey::new(1, 2, 3);
    let mut first: Option<(GlobalVoxel<D>, Vec<u8>)> = None;
    // Every order of the four (4! = 24).
    let mut order = [0usize, 1, 2, 3];
    let mut orders = Vec::new();
    permute(&mut order, 0, &mut orders);
    assert_eq!(orders.len(), 24);
    for o in orders {
        let mut g = map();
        for (seq, &i) in o.iter().enumerate() {
            let (robot, session, residency, n, m) = finals[i];
            let mut s = summary(residency, true, n, m);
            s.obs.scatter = [0.5 * n + m; D];
            g.apply(robot, session, seq as u32, &s);
        }
        let v = g.voxel(&k).unwrap().clone();
        assert_eq!(v.settled.count, 13.5);
        let rec = v.to_record();
        match &first {
            None => first = Some((v, rec)),
            Some((v0, r0)) => {
                assert_eq!(&v, v0, "order {o:?}");
                assert_eq!(&rec, r0, "order {o:?}");
            }
        }
    }
}

fn permute(a: &mut [usize; 4], k: usize, out: &mut Vec<[usize; 4]>) {
    if k == a.len() {
        out.push(*a);
        return;
    }
    for i in k..a.len() {
        a.swap(k, i);
        permute(a, k + 1, out);
        a.swap(k, i);
    }
}

/// A record of version 3 (settled statistics and closed ids only) reads back with its settled statistics as
/// the base; a later final is folded after it, and its copy is still recognised.
#[test]
fn version_3_records_read_back_with_their_sum_as_the_base() {
    let settled = ObsStats::<D> {
        count: 3.0,
        mean: [0.25; D],
        scatter: [0.5; D],
    };
    let mut rec = vec![3u8];
    put_stats(&mut rec, &settled);
    rec.extend_from_slice(&0u32.to_le_bytes());
    rec.extend_from_slice(&1u32.to_le_bytes());
    let id = ContributionId {
        robot: 4,
        session: 2,
        residency: 9,
    };
    put_id(&mut rec, &id);
    rec.extend_from_slice(&0u32.to_le_bytes());
    let v = GlobalVoxel::<D>::from_record(&rec, None).unwrap();
    assert_eq!(
        (v.settled, v.base, v.closed.clone()),
        (settled, settled, vec![id])
    );
    assert!(v.parts.is_empty());
    let mut g = map();
    let k = VoxelKey::new(1, 2, 3);
    g.insert_raw(k, v);
    assert_eq!(
        g.apply(4, 2, 1, &summary(9, true, 1.0, 0.0)),
        Applied::DuplicateFinal
    );
    assert_eq!(
        g.apply(4, 2, 2, &summary(10, true, 1.0, 0.0)),
        Applied::Merged
    );
    let mut expected = settled;
    expected.merge(&summary(10, true, 1.0, 0.0).obs);
    let v = g.voxel(&k).unwrap();
    assert_eq!(v.settled, expected);
    // Written back as version 4, it reads back equal.
    assert_eq!(
        GlobalVoxel::<D>::from_record(&v.to_record(), None).unwrap(),
        *v
    );
}
