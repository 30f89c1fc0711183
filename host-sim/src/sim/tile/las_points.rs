//! Reading a LAS/LAZ file's points as real files demand: a truncated file (fewer points than the header
//! says), a decoder that panics on damaged bytes, withheld points, files too large to hold whole, stray
//! points far from the survey and header bounds that disagree with the points. Apart from [`super::Tile`],
//! which turns the cleaned points into metres, classes and a summary.

use std::path::Path;

/// A `las` error, with what to do when the file ends early.
pub(super) fn las_error(e: &las::Error) -> String {
    match e {
        las::Error::Io(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => format!(
            "{io}: the file ends before its header, records or points do; it is truncated or damaged (rewrite it with `pdal translate` or LAStools' `las2las`)"
        ),
        e => e.to_string(),
    }
}

/// The points an uncompressed LAS file's bytes can hold ((size − offset to the points) / record length);
/// `None` for LAZ or when the header cannot be read.
pub(super) fn uncompressed_points_in(path: &Path) -> Option<u64> {
    let mut head = [0u8; 107];
    let mut f = std::fs::File::open(path).ok()?;
    std::io::Read::read_exact(&mut f, &mut head).ok()?;
    let format = head[104];
    if format & 0x80 != 0 || format & 0x40 != 0 {
        return None; // LAZ sets bit 7 (or 6) of the point format
    }
    let offset = u64::from(u32::from_le_bytes([head[96], head[97], head[98], head[99]]));
    let record = u64::from(u16::from_le_bytes([head[105], head[106]]));
    let size = f.metadata().ok()?.len();
    (record > 0).then(|| size.saturating_sub(offset) / record)
}

/// Run `f` with the panic hook silenced; a panic becomes `Err` with its message.
pub(super) fn quietly<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(f));
    std::panic::set_hook(hook);
    result.map_err(|payload| {
        payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "it panicked".into())
    })
}

/// Points read from a file, in file units, before conversion.
pub(super) struct Raw {
    pub(super) xyz: Vec<[f64; 3]>,
    pub(super) codes: Vec<u8>,
    pub(super) withheld: u64,
    pub(super) stride: u64,
    pub(super) file_points: u64,
}

/// Read every `stride`-th point that is not withheld, in batches (a 100 M-point file never sits in
/// memory whole); at most `available` points (a truncated file holds fewer than its header says).
pub(super) fn read_points(
    reader: &mut las::Reader,
    max_points: usize,
    available: Option<u64>,
) -> Result<Raw, las::Error> {
    let file_points = reader.header().number_of_points();
    let readable = available.map_or(file_points, |a| a.min(file_points));
    let stride = readable.div_ceil(max_points.max(1) as u64).max(1);
    let extended = reader.header().point_format().is_extended;
    let mut data = las::PointDataBuilder::new()
        .for_header(reader.header())
        .build();
    let mut raw = Raw {
        xyz: Vec::with_capacity((file_points / stride) as usize + 1),
        codes: Vec::with_capacity((file_points / stride) as usize + 1),
        withheld: 0,
        stride,
        file_points,
    };
    let mut index = 0u64;
    loop {
        let batch = (readable - index).min(1 << 16);
        if batch == 0 {
            break;
        }
        let got = reader.fill_points(batch, &mut data)?;
        if got == 0 {
            break;
        }
        let records = data.raw_bytes().chunks_exact(data.record_len());
        let columns = data
            .x()
            .zip(data.y())
            .zip(data.z())
            .zip(data.classification());
        for (rec, (((x, y), z), code)) in records.zip(columns) {
            let keep = index.is_multiple_of(stride);
            index += 1;
            if !keep {
                continue;
            }
            // The withheld flag: bit 7 of the classification byte (formats 0–5), bit 2 of the
            // classification flags (formats 6–10).
            let withheld = if extended {
                rec[15] & 0b100 != 0
            } else {
                rec[15] & 0x80 != 0
            };
            if withheld {
                raw.withheld += 1;
                continue;
            }
            raw.xyz.push([x, y, z]);
            raw.codes.push(code);
        }
    }
    Ok(raw)
}

/// The value at quantile `q` of `v` (sampled to at most 100 000 values).
fn quantile(v: &[f64], q: f64) -> f64 {
    let step = (v.len() / 100_000).max(1);
    let mut s: Vec<f64> = v.iter().step_by(step).copied().collect();
    let k = ((s.len() - 1) as f64 * q).round() as usize;
    s.select_nth_unstable_by(k, f64::total_cmp);
    s[k]
}

/// Which points lie with the bulk: per axis, within the 1st–99th percentile band widened by its own
/// width (x, y; at least 1 m) or by three widths (z; at least 50 m). `metres` converts file units.
pub(super) fn with_the_bulk(xyz: &[[f64; 3]], metres: [f64; 3]) -> Vec<bool> {
    let mut keep = vec![true; xyz.len()];
    for axis in 0..3 {
        let v: Vec<f64> = xyz.iter().map(|p| p[axis]).collect();
        let (lo, hi) = (quantile(&v, 0.01), quantile(&v, 0.99));
        let (times, floor) = if axis == 2 { (3.0, 50.0) } else { (1.0, 1.0) };
        let margin = ((hi - lo) * times).max(floor / metres[axis]);
        for (k, x) in keep.iter_mut().zip(&v) {
            *k &= (lo - margin..=hi + margin).contains(x);
        }
    }
    keep
}

/// A note when the header's bounds do not hold the points, or are more than twice their extent.
pub(super) fn header_disagrees(
    b: &las::Bounds,
    lo: [f64; 3],
    hi: [f64; 3],
    metres: [f64; 3],
) -> Option<String> {
    let (hlo, hhi) = ([b.min.x, b.min.y, b.min.z], [b.max.x, b.max.y, b.max.z]);
    let tol = |a: usize, v: f64| 0.01 / metres[a] + 1e-9 * v.abs();
    let outside = (0..3).any(|a| lo[a] < hlo[a] - tol(a, lo[a]) || hi[a] > hhi[a] + tol(a, hi[a]));
    let size = |l: [f64; 3], h: [f64; 3], a: usize| (h[a] - l[a]) * metres[a];
    let larger = (0..2).any(|a| size(hlo, hhi, a) > 2.0 * size(lo, hi, a) + 1.0);
    (outside || larger).then(|| {
        format!(
            "the header's bounds ({:.0} × {:.0} × {:.0} m) disagree with the points' ({:.1} × {:.1} × {:.1} m): the points' are used",
            size(hlo, hhi, 0),
            size(hlo, hhi, 1),
            size(hlo, hhi, 2),
            size(lo, hi, 0),
            size(lo, hi, 1),
            size(lo, hi, 2),
        )
    })
}
