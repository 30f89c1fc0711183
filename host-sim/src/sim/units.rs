//! The units of a point cloud's coordinates, read from its CRS, so that a tile in US survey feet and one
//! in metres both come out in metres.
//!
//! Surveys state their CRS in several ways, and each is read: a WKT record (LAS 1.4), with the unit in its
//! `UNIT`/`LENGTHUNIT` nodes or only implied by the EPSG code of its projected CRS; GeoTIFF keys
//! (LAS 1.0–1.3) with a linear-unit key, or only a projected-CRS code. An EPSG code is resolved to its
//! unit through `crs-definitions` (the EPSG dataset as WKT, no PROJ needed). Horizontal and vertical units
//! are read separately (compound CRSs: projected + vertical). What cannot be resolved — no CRS, a
//! user-defined code (32767) without a unit key, a unit code we do not know — is read as metres, and
//! [`Units::source`] says it was assumed, so the one-line summary shows it and `--units` can correct it.
//! Only a CRS whose coordinates are not lengths (geographic degrees, geocentric XYZ) is refused.

use super::wkt::{self, WktNode};

/// One US survey foot in metres (exactly 1200/3937).
pub const US_SURVEY_FOOT_M: f64 = 1200.0 / 3937.0;
/// One international foot in metres.
pub const FOOT_M: f64 = 0.3048;

/// A length unit of a point cloud's coordinates (`--units`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LengthUnit {
    /// Metres (EPSG 9001).
    #[value(alias = "m", alias = "meter", alias = "metres", alias = "meters")]
    Metre,
    /// International feet, 0.3048 m (EPSG 9002).
    #[value(alias = "ft", alias = "feet")]
    Foot,
    /// US survey feet, 1200/3937 m (EPSG 9003).
    #[value(alias = "ftus", alias = "us-ft")]
    UsSurveyFoot,
}

impl LengthUnit {
    /// Metres per unit.
    pub fn metres(self) -> f64 {
        match self {
            Self::Metre => 1.0,
            Self::Foot => FOOT_M,
            Self::UsSurveyFoot => US_SURVEY_FOOT_M,
        }
    }
    /// The unit of an EPSG unit code, if it is one of these.
    pub fn from_epsg(code: u16) -> Option<Self> {
        match code {
            9001 => Some(Self::Metre),
            9002 => Some(Self::Foot),
            9003 => Some(Self::UsSurveyFoot),
            _ => None,
        }
    }
    /// A conversion factor read from a WKT, snapped to the exact factor of a known unit (WKT prints
    /// US survey feet as 0.304800609601219).
    fn snap(factor: f64) -> f64 {
        [Self::Metre, Self::Foot, Self::UsSurveyFoot]
            .into_iter()
            .map(Self::metres)
            .find(|m| (factor / m - 1.0).abs() < 1e-9)
            .unwrap_or(factor)
    }
    fn name_of(factor: f64) -> String {
        if factor == 1.0 {
            "metre".into()
        } else if factor == FOOT_M {
            "foot".into()
        } else if factor == US_SURVEY_FOOT_M {
            "US survey foot".into()
        } else {
            format!("{factor} m")
        }
    }
}

/// Metres per unit of an EPSG unit-of-measure code that a GeoTIFF unit key may hold.
fn epsg_unit_metres(code: u16) -> Option<f64> {
    Some(match code {
        9001 => 1.0,
        9002 => FOOT_M,
        9003 => US_SURVEY_FOOT_M,
        9005 => 0.304_797_265_4,     // Clarke's foot
        9014 => 1.8288,              // fathom
        9030 => 1852.0,              // nautical mile
        9031 => 1.000_013_596_5,     // German legal metre
        9033 => 20.116_840_233_68,   // US survey chain
        9034 => 0.201_168_402_336_8, // US survey link
        9035 => 1_609.347_218_694,   // US survey mile
        9036 => 1000.0,              // kilometre
        9037 => 0.914_391_796_2,     // Clarke's yard
        9041 => 0.304_799_471_538_5, // British foot (Sears 1922)
        9070 => 0.304_800_749_1,     // British foot (1865)
        9080 => 0.304_799_510_2,     // Indian foot
        9093 => 1_609.344,           // statute mile
        9094 => 0.304_799_710_181_5, // Gold Coast foot
        9095 => 0.304_800_749_1,     // British foot (1936)
        9096 => 0.9144,              // yard
        9097 => 20.1168,             // chain
        9098 => 0.201_168,           // link
        9300 => 0.304_799_5,         // British foot (Sears 1922 truncated)
        _ => return None,
    })
}

/// Metres per unit of the common vertical CRSs by EPSG code (`crs-definitions` holds no vertical CRS).
fn vertical_crs_metres(code: u32) -> Option<f64> {
    Some(match code {
        // NAVD88, EGM96, EGM2008, MSL, NAP, ODN, AHD, NN2000, RH2000, DHHN2016, DHHN92 heights in metres.
        5703 | 5773 | 3855 | 5714 | 5709 | 5701 | 5711 | 5941 | 5613 | 7837 | 5783 => 1.0,
        6360 | 5702 | 8052 => US_SURVEY_FOOT_M, // NAVD88 (ftUS), NGVD29 (ftUS), MSL (ftUS)
        8228 | 8050 => FOOT_M,                  // NAVD88 (ft), MSL (ft)
        _ => return None,
    })
}

/// The units of a tile's coordinates and where they were read.
#[derive(Clone, Debug, PartialEq)]
pub struct Units {
    /// Metres per horizontal (x, y) unit.
    pub horizontal: f64,
    /// Metres per vertical (z) unit.
    pub vertical: f64,
    /// Where the units come from (`from the WKT`, `from the GeoTIFF keys`, `--units`, or `assumed: …`).
    pub source: String,
}

impl Units {
    /// One unit for all three axes.
    pub fn uniform(unit: LengthUnit, source: &str) -> Self {
        Self {
            horizontal: unit.metres(),
            vertical: unit.metres(),
            source: source.into(),
        }
    }
    /// Metres on every axis, assumed for the reason given.
    fn assumed(why: &str) -> Self {
        Self::uniform(
            LengthUnit::Metre,
            &format!("assumed: {why}; --units to change"),
        )
    }
    /// Whether the units were assumed rather than read.
    pub fn is_assumed(&self) -> bool {
        self.source.starts_with("assumed")
    }
    /// "US survey foot (from the WKT)" or "metre horizontally, US survey foot vertically (…)".
    pub fn describe(&self) -> String {
        let (h, v) = (
            LengthUnit::name_of(self.horizontal),
            LengthUnit::name_of(self.vertical),
        );
        if h == v {
            format!("{h} ({})", self.source)
        } else {
            format!("{h} horizontally, {v} vertically ({})", self.source)
        }
    }
}

/// A CRS whose coordinates are not lengths on a plane.
#[derive(Debug, thiserror::Error)]
pub enum CrsError {
    /// The coordinates are angles.
    #[error("the CRS is geographic ({0}): coordinates are degrees, not lengths; reproject the file to a projected CRS in metres or feet (e.g. `pdal translate in.laz out.laz reprojection --filters.reprojection.out_srs=EPSG:<your UTM zone>`)")]
    Geographic(String),
    /// The coordinates are Earth-centred XYZ.
    #[error("the CRS is geocentric ({0}): z is not up; reproject the file to a projected CRS in metres or feet (e.g. `pdal translate in.laz out.laz reprojection --filters.reprojection.out_srs=EPSG:<your UTM zone>`)")]
    Geocentric(String),
}

/// The units a LAS header's CRS gives: the WKT record first (LAS 1.4's CRS record), else the GeoTIFF keys;
/// `None` when the file has neither.
pub fn units_of(header: &las::Header) -> Result<Option<Units>, CrsError> {
    if let Some(bytes) = header.get_wkt_crs_bytes() {
        let text = String::from_utf8_lossy(bytes);
        if let Some(units) = wkt_units(text.trim_end_matches('\0').trim(), "the WKT")? {
            return Ok(Some(units));
        }
    }
    geotiff_units(header)
}

const PROJECTED: &[&str] = &["PROJCS", "PROJCRS", "PROJECTEDCRS"];
const LOCAL: &[&str] = &["LOCAL_CS", "ENGCRS", "ENGINEERINGCRS"];
const VERTICAL: &[&str] = &["VERT_CS", "VERTCRS", "VERTICALCRS"];
const GEOGRAPHIC: &[&str] = &["GEOGCS", "GEOGCRS", "GEOGRAPHICCRS", "BASEGEOGCRS"];
const GEODETIC: &[&str] = &["GEOCCS", "GEODCRS", "GEODETICCRS"];

/// The conversion factor of a `UNIT` node: its number, else a unit known by name.
fn unit_factor(n: &WktNode) -> Option<f64> {
    match n.numbers.first() {
        Some(&f) if f.is_finite() && f > 0.0 => Some(LengthUnit::snap(f)),
        _ => {
            let name = n.strings.first()?.to_lowercase();
            match name.as_str() {
                "metre" | "meter" | "m" => Some(1.0),
                "foot" | "feet" | "ft" | "international foot" => Some(FOOT_M),
                _ if name.contains("us") && (name.contains("foot") || name.contains("ft")) => {
                    Some(US_SURVEY_FOOT_M)
                }
                _ => None,
            }
        }
    }
}

/// Units of an EPSG projected or compound CRS code, through its WKT in `crs-definitions`.
fn epsg_crs_units(code: u32) -> Result<Option<Units>, CrsError> {
    let Some(def) = u16::try_from(code)
        .ok()
        .and_then(crs_definitions::from_code)
    else {
        return Ok(None);
    };
    // The dataset's WKT always carries its unit: one level of lookup, no recursion.
    wkt_units_at(def.wkt, &format!("EPSG:{code}"), false)
}

/// Metres per unit from a WKT's projected (or local) and vertical CRS; `None` if the text is not WKT or
/// names no horizontal CRS.
pub fn wkt_units(text: &str, whence: &str) -> Result<Option<Units>, CrsError> {
    wkt_units_at(text, whence, true)
}

fn wkt_units_at(text: &str, whence: &str, lookup: bool) -> Result<Option<Units>, CrsError> {
    let Some(root) = wkt::parse(text) else {
        return Ok(None);
    };
    let Some(horizontal) = root.find(PROJECTED).or_else(|| root.find(LOCAL)) else {
        if let Some(g) = root.find(GEODETIC) {
            // WKT 2 writes geographic CRSs as GEODCRS too: its CS says which.
            let cartesian = g
                .children
                .iter()
                .any(|c| c.key == "CS" && c.children.iter().any(|w| w.key == "CARTESIAN"));
            let name = g.strings.first().cloned().unwrap_or_default();
            return Err(if g.key == "GEOCCS" || cartesian {
                CrsError::Geocentric(name)
            } else {
                CrsError::Geographic(name)
            });
        }
        if let Some(g) = root.find(GEOGRAPHIC) {
            return Err(CrsError::Geographic(
                g.strings.first().cloned().unwrap_or_default(),
            ));
        }
        return Ok(None);
    };
    let mut source = format!("from {whence}");
    let h = match horizontal.length_unit().and_then(unit_factor) {
        Some(h) => h,
        None => match horizontal.epsg().filter(|_| lookup).map(epsg_crs_units) {
            Some(Ok(Some(u))) => {
                source = format!("from {whence}'s EPSG:{}", horizontal.epsg().unwrap_or(0));
                u.horizontal
            }
            Some(Err(e)) => return Err(e),
            _ => {
                let name = horizontal.strings.first().cloned().unwrap_or_default();
                return Ok(Some(Units::assumed(&format!(
                    "{whence} names the CRS \"{name}\" but no unit"
                ))));
            }
        },
    };
    let vertical = root.find(VERTICAL);
    let v = vertical
        .and_then(|n| n.length_unit().and_then(unit_factor))
        .or_else(|| {
            vertical
                .and_then(WktNode::epsg)
                .and_then(vertical_crs_metres)
        })
        .unwrap_or(h);
    Ok(Some(Units {
        horizontal: h,
        vertical: v,
        source,
    }))
}

/// The GeoTIFF keys' u16 values (key id → value), read leniently: an entry that points into the double or
/// ASCII records is skipped rather than failing the whole directory (the `las` crate refuses such files).
fn geokeys(header: &las::Header) -> Vec<(u16, u16)> {
    let Some(vlr) = header
        .all_vlrs()
        .find(|v| v.user_id.trim_end_matches('\0') == "LASF_Projection" && v.record_id == 34735)
    else {
        return Vec::new();
    };
    let words: Vec<u16> = vlr
        .data
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    let count = words.get(3).map_or(0, |&n| usize::from(n));
    words
        .get(4..)
        .unwrap_or(&[])
        .chunks_exact(4)
        .take(count)
        .filter(|e| e[1] == 0)
        .map(|e| (e[0], e[3]))
        .collect()
}

/// Units from the GeoTIFF keys: ProjLinearUnits (3076) and VerticalUnits (4099) where given, else the
/// EPSG codes of ProjectedCSType (3072) and VerticalCSType (4096).
fn geotiff_units(header: &las::Header) -> Result<Option<Units>, CrsError> {
    let keys = geokeys(header);
    if keys.is_empty() {
        return Ok(None);
    }
    let key = |id: u16| keys.iter().find(|k| k.0 == id).map(|k| k.1);
    // GTModelTypeGeoKey: 1 projected, 2 geographic, 3 geocentric.
    match key(1024) {
        Some(2) => return Err(CrsError::Geographic("GeoTIFF model type 2".into())),
        Some(3) => return Err(CrsError::Geocentric("GeoTIFF model type 3".into())),
        _ => {}
    }
    let epsg = |code: Option<u16>| code.filter(|c| (1024..32767).contains(c));
    let projected = epsg(key(3072));
    // A unit key holding a CRS code instead of a unit code (seen in the wild: 32632) is read as that CRS.
    let unit_key = |id: u16| -> Result<Option<f64>, CrsError> {
        let Some(code) = key(id) else { return Ok(None) };
        if let Some(m) = epsg_unit_metres(code) {
            return Ok(Some(m));
        }
        Ok(epsg_crs_units(u32::from(code))?.map(|u| u.horizontal))
    };
    let mut source = "from the GeoTIFF keys".to_string();
    let h = match unit_key(3076)? {
        Some(h) => h,
        None => match projected
            .map(|c| epsg_crs_units(u32::from(c)))
            .transpose()?
        {
            Some(Some(u)) => {
                source = format!("from the GeoTIFF keys' EPSG:{}", projected.unwrap_or(0));
                u.horizontal
            }
            _ if key(1024) != Some(1) && projected.is_none() && epsg(key(2048)).is_some() => {
                return Err(CrsError::Geographic(format!(
                    "GeoTIFF keys: geographic CRS EPSG:{} and no projected CRS",
                    key(2048).unwrap_or(0)
                )));
            }
            _ => {
                let what = match key(3072) {
                    Some(c) => {
                        format!("the GeoTIFF keys name the projected CRS {c} but no unit we know")
                    }
                    None => "the GeoTIFF keys give no projected CRS or unit".into(),
                };
                return Ok(Some(Units::assumed(&what)));
            }
        },
    };
    let v = match unit_key(4099)? {
        Some(v) => v,
        None => epsg(key(4096))
            .and_then(|c| vertical_crs_metres(u32::from(c)))
            .unwrap_or(h),
    };
    Ok(Some(Units {
        horizontal: h,
        vertical: v,
        source,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header_with_keys(keys: &[(u16, u16)]) -> las::Header {
        let mut data: Vec<u16> = vec![1, 1, 0, keys.len() as u16];
        for &(id, v) in keys {
            data.extend([id, 0, 1, v]);
        }
        let mut b = las::Builder::from((1, 2));
        b.vlrs.push(las::Vlr {
            user_id: "LASF_Projection".into(),
            record_id: 34735,
            description: String::new(),
            data: data.iter().flat_map(|w| w.to_le_bytes()).collect(),
        });
        b.into_header().unwrap()
    }

    #[test]
    fn wkt_units_of_projected_and_compound_crs() {
        let ftus = r#"COMPD_CS["x",PROJCS["NAD83(2011) / Nebraska (ftUS)",GEOGCS["NAD83(2011)",DATUM["D",SPHEROID["GRS 1980",6378137,298.257222101]],UNIT["degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic_2SP"],PARAMETER["false_easting",1640416.6667],UNIT["US survey foot",0.304800609601219,AUTHORITY["EPSG","9003"]],AXIS["X",EAST]],VERT_CS["NAVD88 height (m)",VERT_DATUM["North American Vertical Datum 1988",2005],UNIT["metre",1.0]]]"#;
        let u = wkt_units(ftus, "the WKT").unwrap().unwrap();
        assert_eq!(u.horizontal, US_SURVEY_FOOT_M);
        assert_eq!(u.vertical, 1.0);
        let wkt2 = r#"PROJCRS["WGS 84 / UTM zone 33N",BASEGEOGCRS["WGS 84",ANGLEUNIT["degree",0.0174532925199433]],CONVERSION["UTM zone 33N",PARAMETER["False easting",500000,LENGTHUNIT["metre",1]]],CS[Cartesian,2],AXIS["(E)",east,ORDER[1],LENGTHUNIT["metre",1]],AXIS["(N)",north,ORDER[2],LENGTHUNIT["metre",1]],ID["EPSG",32633]]"#;
        let u = wkt_units(wkt2, "the WKT").unwrap().unwrap();
        assert_eq!((u.horizontal, u.vertical), (1.0, 1.0));
        let geo = r#"GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],UNIT["degree",0.0174532925199433]]"#;
        assert!(matches!(
            wkt_units(geo, "the WKT"),
            Err(CrsError::Geographic(_))
        ));
        let geod2 = r#"GEODCRS["WGS 84",DATUM["World Geodetic System 1984",ELLIPSOID["WGS 84",6378137,298.257223563]],CS[ellipsoidal,2],ANGLEUNIT["degree",0.0174532925199433]]"#;
        assert!(matches!(
            wkt_units(geod2, "the WKT"),
            Err(CrsError::Geographic(_))
        ));
        let geoc = r#"GEOCCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],UNIT["metre",1]]"#;
        assert!(matches!(
            wkt_units(geoc, "the WKT"),
            Err(CrsError::Geocentric(_))
        ));
        let odd = r#"PROJCS["x",UNIT["link",0.201168]]"#;
        assert_eq!(
            wkt_units(odd, "the WKT").unwrap().unwrap().horizontal,
            0.201168
        );
    }

    #[test]
    fn wkt_without_unit_nodes_resolves_its_epsg_code() {
        // No UNIT node anywhere: the projected CRS's EPSG code gives it (2994 is Oregon GIC Lambert, ft).
        let ft = r#"PROJCS["NAD83(HARN) / Oregon GIC Lambert (ft)",AUTHORITY["EPSG","2994"]]"#;
        let u = wkt_units(ft, "the WKT").unwrap().unwrap();
        assert_eq!((u.horizontal, u.vertical), (FOOT_M, FOOT_M));
        assert_eq!(u.source, "from the WKT's EPSG:2994");
        // A vertical CRS named only by its code: NAVD88 height (ftUS) under UTM in metres.
        let c = r#"COMPD_CS["c",PROJCS["WGS 84 / UTM zone 32N",AUTHORITY["EPSG","32632"]],VERT_CS["NAVD88 height (ftUS)",AUTHORITY["EPSG","6360"]]]"#;
        let u = wkt_units(c, "the WKT").unwrap().unwrap();
        assert_eq!((u.horizontal, u.vertical), (1.0, US_SURVEY_FOOT_M));
        // No unit and no code: metres, said to be assumed.
        let u = wkt_units(r#"PROJCS["custom"]"#, "the WKT")
            .unwrap()
            .unwrap();
        assert!(u.is_assumed() && u.horizontal == 1.0, "{u:?}");
        // Not WKT at all: no CRS.
        assert_eq!(wkt_units("not wkt", "the WKT").unwrap(), None);
    }

    #[test]
    fn geotiff_keys_in_every_form() {
        let units = |keys: &[(u16, u16)]| units_of(&header_with_keys(keys));
        // EPSG:32632 (WGS 84 / UTM zone 32N) as the projected CRS, no unit key: metres.
        let u = units(&[(1024, 1), (3072, 32632)]).unwrap().unwrap();
        assert_eq!((u.horizontal, u.vertical), (1.0, 1.0));
        assert_eq!(u.source, "from the GeoTIFF keys' EPSG:32632");
        // The same code in the linear-unit key (a writer's mistake seen in the wild): still metres.
        let u = units(&[(3072, 32632), (3076, 32632)]).unwrap().unwrap();
        assert_eq!(u.horizontal, 1.0);
        // North Carolina (ftUS) by code; NAVD88 height (m) as the vertical CRS.
        let u = units(&[(1024, 1), (3072, 2264), (4096, 5703)])
            .unwrap()
            .unwrap();
        assert_eq!((u.horizontal, u.vertical), (US_SURVEY_FOOT_M, 1.0));
        // User-defined CRS with explicit units: international feet horizontally, US survey feet up.
        let u = units(&[(1024, 1), (3072, 32767), (3076, 9002), (4099, 9003)])
            .unwrap()
            .unwrap();
        assert_eq!((u.horizontal, u.vertical), (FOOT_M, US_SURVEY_FOOT_M));
        // User-defined CRS and no unit: metres, said to be assumed.
        let u = units(&[(1024, 1), (3072, 32767)]).unwrap().unwrap();
        assert!(u.is_assumed(), "{u:?}");
        // Geographic, by model type or by a lone geographic CRS; geocentric.
        assert!(matches!(units(&[(1024, 2)]), Err(CrsError::Geographic(_))));
        assert!(matches!(
            units(&[(2048, 4326)]),
            Err(CrsError::Geographic(_))
        ));
        assert!(matches!(units(&[(1024, 3)]), Err(CrsError::Geocentric(_))));
        // No keys: no CRS.
        assert_eq!(units(&[]).unwrap(), None);
    }
}
