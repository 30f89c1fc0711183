//! A new robot's classes, end to end: `host-sim feature-space --classes floor,wall,sofa --out DIR` writes
//! the files committed in `examples/feature-space/` (checked byte for byte, so the constants below are the
//! command's); a robot built on DIR's constants (`feature_space.rs`: the feature-space id, the int8 scale,
//! the per-class prototypes) — the host twin of a firmware, the same `Mapper` code — maps a room through a
//! noisy 3-class segmenter (`ClassPrototypes::mix` per point), streams it; `host-sim base-station` receives
//! the bytes, and `host-sim map-query` with DIR's `pca.npz` decodes the classes (and a query in other
//! words) — a `pca.npz` of another feature space is refused.

use host_sim::link::SplitMix;
use latentbki::decode::{Codebook, Pca};
use latentbki::key::VoxelKey;
use latentbki::nalgebra::{Isometry3, Translation3, UnitQuaternion};
use latentbki::{packed_len, EncoderSettings, MapConfig, Mapper, Setup};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The committed output of `feature-space --classes floor,wall,sofa`, as a firmware includes it.
mod feature_space {
    include!("../../examples/feature-space/feature_space.rs");
}
use feature_space::{CLASSES, FEATURE_SPACE, PROTOTYPES};

use host_sim::sim::vocab::D;
type Robot = Mapper<D, 8192, { packed_len(D) }, 8192, 512>;
static SETUP: Setup =
    Setup::new(MapConfig::DEFAULT, 4.5, EncoderSettings::new(5, 1)).with_classes(&PROTOTYPES);

fn committed() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/feature-space")
}

fn host_sim(args: &[&std::ffi::OsStr]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .output()
        .unwrap()
}

fn text(o: &std::process::Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

#[test]
fn the_command_writes_the_committed_feature_space_and_prints_its_id() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("new/robot"); // folders are created
    let o = host_sim(&[
        "feature-space".as_ref(),
        "--classes".as_ref(),
        "floor,wall,sofa".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(
        t.lines()
            .any(|l| l == format!("feature space id: {FEATURE_SPACE:#010x}")),
        "{t}"
    );
    assert!(t.contains("prototype decodes to itself"), "{t}");
    for f in ["pca.npz", "feature_space.rs", "vocabulary.tsv"] {
        assert!(
            std::fs::read(out.join(f)).unwrap() == std::fs::read(committed().join(f)).unwrap(),
            "{f} differs from examples/feature-space/{f}: regenerate it with `cargo run --release -p host-sim -- \
             feature-space --classes floor,wall,sofa --out examples/feature-space`"
        );
    }
    // The id is the CRC of the PCA the base station reads.
    let pca = read_pca(&committed().join("pca.npz"));
    assert_eq!(latentbki::wire::feature_space_id(&pca), FEATURE_SPACE);
    assert!(pca.orthonormality_error() < 1e-5);
}

#[test]
fn a_word_outside_the_committed_vocabulary_is_one_line_naming_the_encoder() {
    let dir = tempfile::tempdir().unwrap();
    let o = host_sim(&[
        "feature-space".as_ref(),
        "--classes".as_ref(),
        "floor,grand piano".as_ref(),
        "--out".as_ref(),
        dir.path().as_os_str(),
    ]);
    let t = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    if cfg!(not(feature = "encoder")) {
        assert_eq!(t.trim_end().lines().count(), 1, "{t}");
        assert!(
            t.contains("\"grand piano\" is not in the committed vocabulary"),
            "{t}"
        );
        assert!(t.contains("--features encoder"), "{t}");
    }
}

/// The room: floor, four walls, a sofa against the far wall. Class of a surface point: 0 floor, 1 wall,
/// 2 sofa (CLASSES' order).
fn room(rng: &mut SplitMix) -> Vec<([f32; 3], usize)> {
    let mut pts = Vec::new();
    let mut jitter = |v: f32| v + (rng.unit() as f32 - 0.5) * 0.04;
    let step = 0.04;
    let (lx, ly, lz) = (4.0f32, 3.0f32, 1.6f32);
    let sofa = |x: f32, y: f32| (1.5..2.7).contains(&x) && y > 2.2;
    let n = |len: f32| (len / step) as usize;
    for i in 0..n(lx) {
        for j in 0..n(ly) {
            let (x, y) = (jitter(i as f32 * step), jitter(j as f32 * step));
            if sofa(x, y) {
                pts.push(([x, y, 0.45], 2)); // the seat
            } else {
                pts.push(([x, y, 0.0], 0));
            }
        }
    }
    for i in 0..n(lx) {
        for k in 0..n(lz) {
            let (x, z) = (jitter(i as f32 * step), jitter(k as f32 * step));
            pts.push(([x, 0.0, z], 1));
            if !((1.5..2.7).contains(&x) && z < 0.45) {
                pts.push(([x, ly, z], 1));
            }
        }
    }
    for j in 0..n(ly) {
        for k in 0..n(lz) {
            let (y, z) = (jitter(j as f32 * step), jitter(k as f32 * step));
            pts.push(([0.0, y, z], 1));
            pts.push(([lx, y, z], 1));
        }
    }
    // The sofa's front.
    for i in 0..n(1.2) {
        for k in 0..n(0.45) {
            pts.push((
                [jitter(1.5 + i as f32 * step), 2.2, jitter(k as f32 * step)],
                2,
            ));
        }
    }
    pts
}

/// A segmenter that is right most of the time: the true class scores 120–255, the others 0–90, and one
/// point in ten is confused (another class scores highest).
fn segment(class: usize, rng: &mut SplitMix) -> [u8; 3] {
    let mut s = [0u8; 3];
    for (k, v) in s.iter_mut().enumerate() {
        *v = if k == class {
            120 + (rng.unit() * 135.0) as u8
        } else {
            (rng.unit() * 90.0) as u8
        };
    }
    if rng.chance(0.1) {
        let other = (class + 1 + (rng.next_u64() % 2) as usize) % 3;
        s[other] = 255;
    }
    s
}

fn read_pca(path: &Path) -> Box<Pca<D, 384>> {
    let mut npz = host_sim::npy_io::NpzReader::open(path).unwrap();
    let (_, mean) = npz.array::<f32>("mean").unwrap();
    let (_, comps) = npz.array::<f32>("components").unwrap();
    let mut pca = Box::new(Pca {
        mean: [0.0; 384],
        components: [[0.0; 384]; D],
    });
    pca.mean.copy_from_slice(&mean);
    for (row, c) in pca.components.iter_mut().zip(comps.chunks_exact(384)) {
        row.copy_from_slice(c);
    }
    pca
}

#[test]
fn a_robot_on_the_constants_streams_classes_the_base_station_decodes_with_the_npz() {
    // The robot: the firmware's loop on the host (its twin), features from the segmenter's scores.
    let mut robot: Box<Robot> = Box::new(Robot::EMPTY);
    robot.configure(&SETUP).expect("setup");
    let mut rng = SplitMix::new(31);
    let origin = [2.0f32, 1.4, 0.3];
    let pose = Isometry3::from_parts(
        Translation3::new(origin[0], origin[1], origin[2]),
        UnitQuaternion::identity(),
    );
    let inv = 1.0 / MapConfig::DEFAULT.voxel_size();
    let mut truth: BTreeMap<VoxelKey, [u32; 3]> = BTreeMap::new();
    let mut uart = host_sim::link::ByteLog(Vec::new());
    let mut codes = [0i8; D];
    for _pass in 0..3 {
        let mut frame = robot.begin_frame(&pose);
        for (p, class) in room(&mut rng) {
            PROTOTYPES
                .mix(&segment(class, &mut rng), &mut codes)
                .expect("a score");
            let sensor = [p[0] - origin[0], p[1] - origin[1], p[2] - origin[2]];
            frame.add_point_i8(sensor, &codes).expect("taken");
            truth
                .entry(VoxelKey::from_position(p, inv).unwrap())
                .or_default()[class] += 1;
        }
        robot.tick(&mut uart, 1 << 20).unwrap();
    }
    robot.drain(&mut uart).unwrap();
    assert_eq!(robot.map().rejections().total(), 0);

    // The base station: receives the bytes into a database, decodes with DIR's pca.npz.
    let dir = tempfile::tempdir().unwrap();
    let (bytes, db) = (dir.path().join("uart.bin"), dir.path().join("map.db"));
    std::fs::write(&bytes, &uart.0).unwrap();
    let o = host_sim(&[
        "base-station".as_ref(),
        bytes.as_os_str(),
        "--map".as_ref(),
        db.as_os_str(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let npz = committed().join("pca.npz");
    let classes = CLASSES.join(",");
    let pictures = dir.path().join("pictures/of/map");
    let o = host_sim(&[
        "map-query".as_ref(),
        db.as_os_str(),
        "--pca".as_ref(),
        npz.as_os_str(),
        "--classes".as_ref(),
        classes.as_ref(),
        "--query".as_ref(),
        "something to sit on".as_ref(),
        "--top".as_ref(),
        "10".as_ref(),
        "--png".as_ref(),
        pictures.as_os_str(),
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    // The pictures: in a folder that did not exist, titled and framed like the demo's (not 1 px a voxel).
    for f in ["labels", "heat", "uncertainty", "gain"] {
        let png = dir.path().join(format!("pictures/of/map-{f}.png"));
        let img = host_sim::png_io::RgbImage::read_png(&png).unwrap();
        if f != "gain" {
            assert!(
                img.width() >= 600 && img.height() >= 400,
                "{f}: {}×{}",
                img.width(),
                img.height()
            );
        }
    }
    // Voxel counts per decoded class against the truth's majority class per voxel.
    let mut want = [0usize; 3];
    for counts in truth.values() {
        want[(0..3).max_by_key(|&c| counts[c]).unwrap()] += 1;
    }
    for (k, name) in CLASSES.iter().enumerate() {
        let got: usize = t
            .lines()
            .find_map(|l| l.trim().strip_prefix(&format!("{name}: ")))
            .and_then(|r| r.strip_suffix(" voxels"))
            .unwrap_or_else(|| panic!("no count for {name}:\n{t}"))
            .parse()
            .unwrap();
        // Voxels the kernel reaches beside the surfaces decode too; the decoded count is at least the
        // surface voxels of that class, less the mixed ones at the class borders.
        assert!(
            got * 10 >= want[k] * 9,
            "{name}: {got} voxels decoded, {} voxels mostly {name}:\n{t}",
            want[k]
        );
    }
    // Open vocabulary: "something to sit on" (not a class) finds the sofa.
    let on_sofa = t
        .lines()
        .filter(|l| l.starts_with("query \"something to sit on\""))
        .filter(|l| {
            let xyz = l.split('(').nth(1).unwrap().split(')').next().unwrap();
            let v: Vec<f32> = xyz.split(", ").map(|s| s.parse().unwrap()).collect();
            (1.3..2.9).contains(&v[0]) && v[1] > 2.0 && v[2] < 0.7
        })
        .count();
    assert!(
        on_sofa >= 9,
        "{on_sofa} of the 10 best voxels on the sofa:\n{t}"
    );

    // Voxel by voxel: every clear surface voxel decodes to its class.
    let map = host_sim::cli::station::read_map(&db).unwrap();
    let map = map.map().expect("a map");
    assert_eq!(map.config().feature_space, FEATURE_SPACE);
    let table = host_sim::sim::vocab::TextEmbeddings::builtin();
    let book =
        Codebook::<D, 8>::from_pca(&read_pca(&npz), &table.embeddings(&CLASSES).unwrap()).unwrap();
    let (mut right, mut clear) = (0, 0);
    for (key, counts) in &truth {
        let n: u32 = counts.iter().sum();
        let major = (0..3).max_by_key(|&c| counts[c]).unwrap();
        if n < 10 || counts[major] * 10 < n * 9 {
            continue;
        }
        clear += 1;
        if map.label(key, &book).map(|(l, _)| l) == Some(major) {
            right += 1;
        }
    }
    assert!(clear > 2000, "{clear} clear voxels");
    // (The few that do not sit beside another class: the kernel's reach blends their neighbours in.)
    assert!(
        right * 100 >= clear * 97,
        "{right} of {clear} clear voxels decode to their class"
    );

    // Another feature space's PCA is refused, in one line.
    let other = dir.path().join("other");
    let o = host_sim(&[
        "feature-space".as_ref(),
        "--classes".as_ref(),
        "floor,wall".as_ref(),
        "--out".as_ref(),
        other.as_os_str(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let o = host_sim(&[
        "map-query".as_ref(),
        db.as_os_str(),
        "--pca".as_ref(),
        other.join("pca.npz").as_os_str(),
        "--classes".as_ref(),
        "floor,wall".as_ref(),
    ]);
    let t = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(t.contains("is not the robots'"), "{t}");
}
