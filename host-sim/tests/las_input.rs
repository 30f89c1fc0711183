//! A user's own point cloud: `host-sim eval --las their.laz` on an airborne tile in metres with classes
//! {1, 2, 3, 4, 5, 17} and relief gives the table and the pictures; a run that sees too little says what to
//! change in one line; `integrate` takes a `.laz` with its features beside it.
//!
//! The tile in metres is `data/relief-tile-metres.laz`, made by [`their_tile`] from the committed tile
//! (laspy's, BSD-2-Clause; see data/README.md): its coordinates converted from US survey feet to metres,
//! 9 m of relief added (a 1:2 slope along x; the flight used to hold 2 m above the lowest ground point),
//! buildings relabelled 17 (bridge deck), noise and the ground of a 4 m strip relabelled 1 (unclassified),
//! written as LAS 1.4 / LAZ with a WKT CRS in metres (UTM zone 33N; the placement is arbitrary). A test
//! checks that the committed file is what the recipe makes (`BLESS=1` rewrites it).

use host_sim::sim::tile::{self, LengthUnit, TerrainFollowing, Tile, TileRun, US_SURVEY_FOOT_M};
use std::path::{Path, PathBuf};
use std::process::Command;

const UTM33N: &str = r#"PROJCS["WGS 84 / UTM zone 33N",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],PARAMETER["central_meridian",15],PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AUTHORITY["EPSG","32633"]]"#;

/// Slope added along x (metres of height per metre).
const SLOPE: f64 = 0.5;

fn committed_tile() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/file_with_both_wkt_and_geotiff_vlrs.las")
}

fn relief_tile() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/relief-tile-metres.laz")
}

fn points_of(path: &Path) -> Vec<(f64, f64, f64, u8)> {
    let data = las::Reader::from_path(path).unwrap().read_all().unwrap();
    data.x()
        .zip(data.y())
        .zip(data.z())
        .zip(data.classification())
        .map(|(((x, y), z), c)| (x, y, z, c))
        .collect()
}

#[test]
fn the_committed_relief_tile_is_what_the_recipe_makes() {
    let dir = tempfile::tempdir().unwrap();
    let made = dir.path().join("made.laz");
    their_tile(&made);
    if std::env::var_os("BLESS").is_some() {
        std::fs::copy(&made, relief_tile()).unwrap();
    }
    let (a, b) = (points_of(&made), points_of(&relief_tile()));
    assert_eq!(a.len(), 25_408);
    assert!(
        a == b,
        "data/relief-tile-metres.laz differs from the recipe: BLESS=1 rewrites it"
    );
}

/// Write `points` (x, y, z in the CRS's units, ASPRS code) as a LAS 1.4 point format 6 file at 0.001
/// resolution; `.laz` compresses.
fn write_las(path: &Path, points: &[(f64, f64, f64, u8)], wkt: Option<&str>) {
    let mut b = las::Builder::from((1, 4));
    b.point_format = las::point::Format::new(6).unwrap();
    let t = |offset| las::Transform {
        scale: 0.001,
        offset,
    };
    let floor = |f: fn(&(f64, f64, f64, u8)) -> f64| {
        let m = points.iter().map(f).fold(f64::INFINITY, f64::min).floor();
        if m.is_finite() {
            m
        } else {
            0.0
        }
    };
    b.transforms = las::Vector {
        x: t(floor(|p| p.0)),
        y: t(floor(|p| p.1)),
        z: t(floor(|p| p.2)),
    };
    let mut header = b.into_header().unwrap();
    if let Some(wkt) = wkt {
        header.set_wkt_crs(wkt.as_bytes().to_vec()).unwrap();
    }
    let mut w = las::Writer::from_path(path, header).unwrap();
    for &(x, y, z, c) in points {
        w.write_point(las::Point {
            x,
            y,
            z,
            classification: las::point::Classification::new(c).unwrap(),
            return_number: 1,
            number_of_returns: 1,
            gps_time: Some(0.0),
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
}

/// The committed tile as a user's airborne tile in metres, with relief and classes {1,2,3,4,5,17}.
fn their_tile(path: &Path) {
    their_tile_thinned(path, 1);
}

/// [`their_tile`] keeping every `every`-th point.
fn their_tile_thinned(path: &Path, every: usize) {
    let mut r = las::Reader::from_path(committed_tile()).unwrap();
    let data = r.read_all().unwrap();
    let (x0, y0) = (2_445_180.0, 604_300.0);
    let points: Vec<(f64, f64, f64, u8)> = data
        .x()
        .zip(data.y())
        .zip(data.z())
        .zip(data.classification())
        .map(|(((x, y), z), c)| {
            let (x, y, z) = (
                (x - x0) * US_SURVEY_FOOT_M,
                (y - y0) * US_SURVEY_FOOT_M,
                z * US_SURVEY_FOOT_M,
            );
            let code = match c {
                6 => 17,
                7 => 1,
                2 if x < 4.0 => 1,
                c => c,
            };
            (500_100.0 + x, 4_000_200.0 + y, z + SLOPE * x, code)
        })
        .step_by(every)
        .collect();
    write_las(path, &points, Some(UTM33N));
}

fn host_sim(args: &[&str], out: &Path) -> (bool, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .arg("--out")
        .arg(out)
        .env("RUST_BACKTRACE", "1")
        .output()
        .unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn their_laz_in_metres_loads_with_every_class_and_the_robot_follows_its_relief() {
    let laz = relief_tile();
    assert_eq!(&std::fs::read(&laz).unwrap()[..4], b"LASF");
    let t = Tile::from_path(&laz, None).unwrap();
    assert_eq!(t.units.horizontal, 1.0);
    assert_eq!(t.units.source, "from the WKT");
    assert_eq!(
        t.names,
        [
            "unclassified",
            "ground",
            "low vegetation",
            "medium vegetation",
            "high vegetation",
            "bridge deck"
        ]
    );
    assert_eq!(t.codes[0], [1]);
    assert_eq!(t.codes[5], [17]);
    // Same extent as the committed tile in metres (data/README.md: 18.28 × 12.19 m) — read in metres, not
    // taken for feet.
    let (lo, hi) = t.bounds;
    assert!((hi[0] - lo[0] - 18.28).abs() < 0.01 && (hi[1] - lo[1] - 12.19).abs() < 0.01);
    // `--units` overrides the CRS.
    let ft = Tile::from_path(&laz, Some(LengthUnit::Foot)).unwrap();
    assert!((ft.bounds.1[0] / hi[0] - 0.3048).abs() < 1e-4);

    // Terrain following: every pose is between half and one and a half times the altitude above the
    // ground beneath it, although the ground rises 9 m across the tile.
    let (range, altitude) = host_sim::sim::scale::scaled_sensor(&t, 3000);
    assert_eq!((range, altitude), (10.0, 2.0));
    let run = TileRun {
        frames: 24,
        ..TileRun::default()
    };
    let seq = tile::sequence(&t, &run);
    let terrain = TerrainFollowing::new(&t, altitude);
    let heights: Vec<f32> = seq
        .frames
        .iter()
        .map(|f| {
            let p = f.pose.translation.vector;
            p.z - terrain.ground(p.x, p.y).unwrap()
        })
        .collect();
    assert!(
        heights
            .iter()
            .all(|h| (0.5 * altitude - 1e-3..=1.5 * altitude + 1e-3).contains(h)),
        "{heights:?}"
    );
    let climbed = seq
        .frames
        .iter()
        .map(|f| f.pose.translation.vector.z)
        .fold(f32::NEG_INFINITY, f32::max)
        - (t.ground_height() + altitude);
    assert!(
        climbed > 3.0,
        "the robot climbs with the ground ({climbed} m)"
    );
    assert!(seq.frames.iter().all(|f| f.points.len() == 3000));
}

#[test]
fn eval_on_their_laz_gives_the_table_and_the_pictures() {
    let dir = tempfile::tempdir().unwrap();
    let laz = relief_tile();
    let out = dir.path().join("out");
    let las = laz.to_str().unwrap();
    let (ok, stdout, stderr) = host_sim(
        &[
            "eval",
            "--las",
            las,
            "--frames",
            "12",
            "--points",
            "1500",
            "--no-sweep",
        ],
        &out,
    );
    assert!(ok, "{stdout}\n{stderr}");
    // What was read, in one line: units from the CRS, the classes by name.
    assert!(
        stdout.contains("units metre (from the WKT)")
            && stdout.contains("1 unclassified")
            && stdout.contains("17 bridge deck"),
        "{stdout}"
    );
    assert!(
        stdout.contains("### Scene: tile relief-tile-metres.laz"),
        "{stdout}"
    );
    // Only their tile ran (not the indoor house), and every method has a row with numbers.
    assert!(!stdout.contains("Scene: indoor"), "{stdout}");
    let column = |label: &str, c: usize| -> f64 {
        let row = stdout
            .lines()
            .find(|l| l.starts_with(&format!("| {label} |")))
            .unwrap_or_else(|| panic!("no row {label}: {stdout}"));
        row.split('|').nth(c).unwrap().trim().parse().unwrap()
    };
    let acc = |label| column(label, 2);
    let observed = |label| column(label, 5);
    // 12 frames leave a quarter of the held-out points in voxels nobody observed: where they were
    // observed, the map beats the network's own labels; the kernel's spreading beats the plain mean.
    let seg = observed("Segmentation only");
    let bki = observed("LatentBKI f32 (f = 3)");
    assert!(
        seg > 40.0 && bki > seg,
        "segmentation {seg}, LatentBKI {bki}"
    );
    assert!(acc("LatentBKI f32 (f = 3)") > acc("VLMap-style mean (f = 1)") + 10.0);
    let device = acc("LatentBKI on-device, quantized (f = 3)");
    let f32_map = acc("LatentBKI f32 (f = 3)");
    assert!(
        (f32_map - device).abs() < 1.0,
        "f32 {f32_map}, device {device}"
    );
    // The query word comes from a class the tile has: no building here ("house"), but high vegetation.
    for f in [
        "tile/semantic_map.png",
        "tile/query_tree.png",
        "tile/uncertainty_eopt.png",
        "tile/sparsification.png",
        "results.md",
    ] {
        let p = out.join(f);
        assert!(
            std::fs::metadata(&p).is_ok_and(|m| m.len() > 1000),
            "{}",
            p.display()
        );
    }
    // The flight's figure, and the scale: chosen by validation on the integrated points, the candidates
    // (from the tile's 0.094 m spacing: the paper's 0.1 m among them) and their scores in results.md.
    assert!(
        stdout.contains("frames per surface: each of the tile's points is returned by"),
        "{stdout}"
    );
    let md = std::fs::read_to_string(out.join("results.md")).unwrap();
    assert!(
        md.contains("Scale chosen by validation: 25 candidates"),
        "{md}"
    );
    assert!(md.contains("| 0.100 | 0.500 | 5.0 | 3 |"), "{md}");
    assert!(
        md.contains("f = 3 (chosen by validation: best of 25 candidates"),
        "{md}"
    );
    // The spacing rule is still there when asked for.
    let (ok, stdout, stderr) = host_sim(
        &[
            "eval",
            "--las",
            las,
            "--frames",
            "4",
            "--points",
            "1500",
            "--no-sweep",
            "--scale",
            "spacing",
        ],
        &out,
    );
    assert!(ok, "{stdout}\n{stderr}");
    assert!(
        stdout
            .contains("map scale: voxel 0.100 m, ℓ = 0.500 m (from the points' spacing ≈ 0.0935 m"),
        "{stdout}"
    );
    assert!(md.contains("| bridge deck | "), "{md}");
}

#[test]
fn a_run_that_sees_too_little_says_what_to_change_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let laz = relief_tile();
    let las = laz.to_str().unwrap();
    let out = dir.path().join("out");
    // Flying 40 m above the ground with a 10 m LiDAR, the robot sees nothing.
    let (ok, stdout, stderr) = host_sim(
        &[
            "eval",
            "--las",
            las,
            "--frames",
            "4",
            "--points",
            "500",
            "--no-sweep",
            "--altitude",
            "40",
        ],
        &out,
    );
    assert!(!ok, "{stdout}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{stderr}");
    assert!(
        lines[0].contains("saw 0 points") && lines[0].contains("--altitude"),
        "{stderr}"
    );
    // Sparse but not empty: a tile thinned to 1 point in 40 (3 points/m²) seen by a 3 m LiDAR.
    let thin = dir.path().join("thin.laz");
    their_tile_thinned(&thin, 40);
    let (ok, _, stderr) = host_sim(
        &[
            "eval",
            "--las",
            thin.to_str().unwrap(),
            "--frames",
            "1",
            "--points",
            "500",
            "--no-sweep",
            "--range",
            "3",
        ],
        &out,
    );
    assert!(!ok);
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{stderr}");
    assert!(
        lines[0].contains("too sparse") && lines[0].contains("raise --range"),
        "{stderr}"
    );
    // Enough points to run, but 0.59 m apart for the 0.1 m voxels the user asked for: the table, then one
    // line saying what to change.
    let (ok, stdout, stderr) = host_sim(
        &[
            "eval",
            "--las",
            thin.to_str().unwrap(),
            "--frames",
            "3",
            "--points",
            "500",
            "--no-sweep",
            "--voxel-size",
            "0.1",
            "--kernel-length",
            "0.5",
        ],
        &out,
    );
    assert!(ok, "{stderr}");
    let hints: Vec<&str> = stdout.lines().filter(|l| l.starts_with("hint:")).collect();
    assert_eq!(hints.len(), 1, "{stdout}");
    assert!(
        hints[0].contains("≈ 0.59 m apart") && hints[0].contains("try --voxel-size 0.60"),
        "{stdout}"
    );
    // An empty file and a file that is not LAS: one line each, naming the file.
    let empty = dir.path().join("empty.las");
    write_las(&empty, &[], Some(UTM33N));
    let garbage = dir.path().join("garbage.laz");
    std::fs::write(&garbage, b"x y z class\n1 2 3 2\n").unwrap();
    for (file, why) in [
        (&empty, "holds no point"),
        (&garbage, "not a LAS or LAZ file"),
    ] {
        let (ok, _, stderr) = host_sim(&["eval", "--las", file.to_str().unwrap()], &out);
        let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
        assert!(!ok && lines.len() == 1, "{stderr}");
        assert!(
            lines[0].contains(&format!("--las {}: ", file.display())) && lines[0].contains(why),
            "{stderr}"
        );
    }
}

#[test]
fn user_and_reserved_classes_get_a_name_and_a_file_without_crs_is_metres() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("user.las");
    let points: Vec<(f64, f64, f64, u8)> = (0..300)
        .map(|i| {
            let code = [9, 64, 200, 0, 1, 30][i % 6];
            (
                500_000.0 + f64::from(i as u32 % 20),
                4_000_000.0 + f64::from(i as u32 / 20),
                100.0,
                code,
            )
        })
        .collect();
    write_las(&path, &points, None);
    let t = Tile::from_path(&path, None).unwrap();
    assert_eq!(
        t.names,
        ["unclassified", "water", "class 30", "class 64", "class 200"]
    );
    assert_eq!(t.codes[0], [0, 1]);
    assert_eq!(t.histogram(), [100, 50, 50, 50, 50]);
    assert_eq!(t.units.horizontal, 1.0);
    assert!(t.units.source.contains("no CRS"), "{}", t.units.source);
    // Unnamed classes get distinct fixed directions, named ones their text embeddings.
    let vocab = host_sim::sim::vocab::TextEmbeddings::builtin();
    let names: Vec<&str> = t.names.iter().map(String::as_str).collect();
    let e = vocab.class_embeddings(&names).unwrap();
    assert_eq!(e[1], *vocab.get("water").unwrap());
    let cos = host_sim::sim::vocab::cosine(&e[3], &e[4]);
    assert!(cos.abs() < 0.3, "{cos}");
    assert_eq!(e[3], vocab.class_embeddings(&["class 64"]).unwrap()[0]);
    assert!(vocab.class_embeddings(&["klass 64"]).is_err());
}

#[test]
fn an_unclassified_survey_loads_and_says_its_accuracy_means_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("raw.las");
    // Codes 0 and 1 are both "unclassified": one class, as a raw survey delivers it.
    let points: Vec<(f64, f64, f64, u8)> = (0..300)
        .map(|i| {
            (
                f64::from(i % 20),
                f64::from(i / 20),
                0.0,
                [0, 1][i as usize % 2],
            )
        })
        .collect();
    write_las(&path, &points, None);
    let t = Tile::from_path(&path, None).unwrap();
    assert_eq!(t.names, ["unclassified"]);
    assert!(
        t.summary().contains("one class only (unclassified)"),
        "{}",
        t.summary()
    );
    // Two classes: no such note.
    let two: Vec<(f64, f64, f64, u8)> = points
        .iter()
        .enumerate()
        .map(|(i, &(x, y, z, _))| (x, y, z, [1, 2][i % 2]))
        .collect();
    write_las(&path, &two, None);
    let t = Tile::from_path(&path, None).unwrap();
    assert!(!t.summary().contains("one class only"), "{}", t.summary());
}

const NEBRASKA_FTUS: &str = r#"PROJCS["NAD83(2011) / Nebraska (ftUS)",GEOGCS["NAD83(2011)",DATUM["NAD83_National_Spatial_Reference_System_2011",SPHEROID["GRS 1980",6378137,298.257222101]],UNIT["degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic_2SP"],UNIT["US survey foot",0.304800609601219,AUTHORITY["EPSG","9003"]],AUTHORITY["EPSG","6517"]]"#;

fn run(args: &[&std::ffi::OsStr]) -> (bool, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(args)
        .env("RUST_BACKTRACE", "1")
        .output()
        .unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn integrate_reads_a_laz_with_its_features_beside_it() {
    use host_sim::npy_io::{read_map_npz, write_npy};
    use host_sim::ReferenceMap;
    const D: usize = 8;
    let dir = tempfile::tempdir().unwrap();
    // 500 points in a 6 × 6 × 3 ft box, geo-referenced in US survey feet.
    let mut s = 0x2545_F491u32;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        f64::from(s) / f64::from(u32::MAX)
    };
    let points: Vec<(f64, f64, f64, u8)> = (0..500)
        .map(|_| {
            (
                2_445_180.0 + 6.0 * next(),
                604_300.0 + 6.0 * next(),
                1_354.0 + 3.0 * next(),
                2,
            )
        })
        .collect();
    let features: Vec<f32> = (0..500 * D).map(|_| next() as f32 - 0.5).collect();
    let write_features = |path: &Path, rows: usize| {
        let mut bytes = Vec::new();
        write_npy(
            &mut bytes,
            &[rows as u64, D as u64],
            features[..rows * D].iter().copied(),
        )
        .unwrap();
        std::fs::write(path, bytes).unwrap();
    };
    let laz = dir.path().join("scan.laz");
    write_las(&laz, &points, Some(NEBRASKA_FTUS));
    write_features(&dir.path().join("scan.npy"), 500);

    // What the command must compute: the file's points, in metres from its minimum corner.
    let mut r = las::Reader::from_path(&laz).unwrap();
    let min = r.header().bounds().min;
    let data = r.read_all().unwrap();
    let positions: Vec<[f32; 3]> = data
        .x()
        .zip(data.y())
        .zip(data.z())
        .map(|((x, y), z)| {
            [
                ((x - min.x) * US_SURVEY_FOOT_M) as f32,
                ((y - min.y) * US_SURVEY_FOOT_M) as f32,
                ((z - min.z) * US_SURVEY_FOOT_M) as f32,
            ]
        })
        .collect();
    assert!(positions.iter().all(|p| p[0] < 1.83 && p[2] < 0.92));
    let feats: Vec<[f32; D]> = features
        .chunks_exact(D)
        .map(|c| c.try_into().unwrap())
        .collect();
    let mut expected = ReferenceMap::<D>::new(latentbki::MapConfig::default()).unwrap();
    expected.integrate(
        &latentbki::nalgebra::Isometry3::identity(),
        &positions,
        &feats,
    );

    let out = dir.path().join("map.npz");
    let (ok, stdout, stderr) = run(&[
        "integrate".as_ref(),
        laz.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("units US survey foot (from the WKT)"),
        "{stdout}"
    );
    let map = read_map_npz(&out).unwrap();
    assert_eq!(map.dim, D);
    assert_eq!(map.keys.len(), expected.len());
    assert!(expected.len() > 100);
    for (i, k) in map.keys.iter().enumerate() {
        let v = expected
            .get(&latentbki::key::VoxelKey::new(k[0], k[1], k[2]))
            .expect("voxel exists");
        // The observation map's gather equals the paper's update to f32 rounding.
        assert!((map.lambda[i] - v.lambda).abs() <= 1e-5 * v.lambda);
        for d in 0..D {
            assert!((map.mean[i * D + d] - v.mean[d]).abs() <= 1e-5 * (1.0 + v.mean[d].abs()));
        }
    }

    // Mistakes get one clear line each.
    let short = dir.path().join("short.laz");
    std::fs::copy(&laz, &short).unwrap();
    write_features(&dir.path().join("short.npy"), 499);
    let (ok, _, err) = run(&[
        "integrate".as_ref(),
        short.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert!(
        !ok && err.contains("499 feature rows for the 500 points"),
        "{err}"
    );
    let bare = dir.path().join("bare.laz");
    std::fs::copy(&laz, &bare).unwrap();
    let (ok, _, err) = run(&[
        "integrate".as_ref(),
        bare.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert!(
        !ok && err.contains("bare.npy") && err.contains("(N, D) float32"),
        "{err}"
    );
    let (ok, _, err) = run(&[
        "integrate".as_ref(),
        laz.as_os_str(),
        dir.path().join("scan.npy").as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert!(!ok && err.contains("not both"), "{err}");
}

/// Every LAS version and point format the `las` crate writes, each CRS form, a header whose bounds are
/// wrong, a stray point, a single class without ground: each loads with the scale and units expected, and
/// eval runs to `results.md` on one of them (small, fast).
#[test]
fn every_version_format_and_crs_form_loads() {
    let dir = tempfile::tempdir().unwrap();
    let grid = |n: usize, code: u8| -> Vec<(f64, f64, f64, u8)> {
        (0..n)
            .map(|i| {
                let (x, y) = ((i % 40) as f64 * 0.5, (i / 40) as f64 * 0.5);
                (326_400.0 + x, 6_724_100.0 + y, 10.0 + 0.1 * x, code)
            })
            .collect()
    };
    for (minor, format) in [
        (0, 0),
        (1, 1),
        (2, 2),
        (2, 3),
        (3, 4),
        (3, 5),
        (4, 6),
        (4, 7),
        (4, 8),
        (4, 9),
        (4, 10),
    ] {
        let path = dir.path().join(format!("v1{minor}_f{format}.las"));
        let mut b = las::Builder::from((1, minor));
        b.point_format = las::point::Format::new(format).unwrap();
        b.transforms = las::Vector {
            x: las::Transform {
                scale: 0.01,
                offset: 326_000.0,
            },
            y: las::Transform {
                scale: 0.01,
                offset: 6_724_000.0,
            },
            z: las::Transform {
                scale: 0.01,
                offset: 0.0,
            },
        };
        let mut w = las::Writer::from_path(&path, b.into_header().unwrap()).unwrap();
        let fmt = las::point::Format::new(format).unwrap();
        for (x, y, z, c) in grid(800, 2) {
            let mut p = las::Point {
                x,
                y,
                z,
                classification: las::point::Classification::new(c).unwrap(),
                return_number: 1,
                number_of_returns: 1,
                ..Default::default()
            };
            if fmt.has_gps_time {
                p.gps_time = Some(0.0);
            }
            if fmt.has_color {
                p.color = Some(las::Color::new(1, 2, 3));
            }
            if fmt.has_nir {
                p.nir = Some(4);
            }
            if fmt.has_waveform {
                p.waveform = Some(Default::default());
            }
            w.write_point(p).unwrap();
        }
        w.close().unwrap();
        let t = Tile::from_path(&path, None)
            .unwrap_or_else(|e| panic!("1.{minor} format {format}: {e}"));
        assert_eq!(t.points.len(), 800, "1.{minor} format {format}");
        assert!((t.spacing - 0.5).abs() < 0.05, "{}", t.spacing);
        assert_eq!(t.names, ["ground"]);
    }
    // EPSG:32632 by WKT code only (no UNIT), a stray point 5 km off (the header's bounds include it),
    // one class and no ground: eval runs and states the scale.
    let mut points = grid(1600, 5);
    points.push((321_400.0, 6_724_100.0, 10.0, 5));
    let path = dir.path().join("utm32.las");
    write_las(
        &path,
        &points,
        Some(r#"PROJCS["WGS 84 / UTM zone 32N",AUTHORITY["EPSG","32632"]]"#),
    );
    let t = Tile::from_path(&path, None).unwrap();
    assert_eq!(t.units.source, "from the WKT's EPSG:32632");
    assert_eq!(t.points.len(), 1600);
    assert!(t.notes.iter().any(|n| n.contains("stray")), "{:?}", t.notes);
    let out = dir.path().join("out");
    let (ok, stdout, stderr) = host_sim(
        &[
            "eval",
            "--las",
            path.to_str().unwrap(),
            "--frames",
            "6",
            "--points",
            "400",
            "--no-sweep",
        ],
        &out,
    );
    assert!(ok, "{stdout}\n{stderr}");
    assert!(stdout.contains("map scale: voxel "), "{stdout}");
    assert!(
        stdout.contains("(chosen by validation: best of 25 candidates"),
        "{stdout}"
    );
    let md = std::fs::read_to_string(out.join("results.md")).unwrap();
    assert!(md.contains("| high vegetation | "), "{md}");
    assert!(out.join("tile/query_tree.png").exists());
}
