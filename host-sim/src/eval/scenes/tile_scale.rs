//! The tile's scale: the map configuration, sensor range and flying height a tile scene runs at — given,
//! measured from the tile, or chosen by validation once the frames are encoded — and why a window cannot
//! hold a range.

use super::*;

impl SceneSource {
    /// The tile's map configuration, sensor range and flying height, and phrases saying where they came
    /// from: given (the options, or the paper's defaults for the built-in tile), measured from the tile, or
    /// to be chosen by validation once the frames are encoded.
    pub(super) fn tile_scale(t: &Tile, options: &SceneOptions) -> Result<TileScale> {
        let (range, _) = tile::scaled_sensor(t, options.tile_points);
        let flight_given = options.tile.range.is_some();
        let range = options.tile.range.unwrap_or(range);
        let altitude = options.tile.altitude.unwrap_or(range / 5.0);
        let rule = options.tile.scale == Some(ScaleArg::Spacing);
        let asked = options.tile.scale == Some(ScaleArg::Validate);
        let (config, map_note, validate) = match &options.tile_map {
            Some(map) if !map.scale_given() && !rule => {
                let voxel = scale::voxel_for_spacing(t.spacing);
                (
                    map.config_with_voxel(voxel)?,
                    String::new(),
                    Some(map.filter_size),
                )
            }
            Some(map) => {
                let voxel = scale::voxel_for_spacing(t.spacing);
                let config = map.config_with_voxel(voxel)?;
                let note = match (map.voxel_size.is_some(), map.kernel_length.is_some()) {
                    (false, false) => format!(
                        "from the points' spacing ≈ {} m: voxel ≈ spacing, ℓ = {} voxels",
                        significant(t.spacing),
                        scale::KERNEL_VOXELS
                    ),
                    (true, true) => "given".to_string(),
                    (true, false) => format!("voxel given, ℓ = {} voxels", scale::KERNEL_VOXELS),
                    (false, true) => format!(
                        "ℓ given, voxel from the points' spacing ≈ {} m",
                        significant(t.spacing)
                    ),
                };
                (config, note, None)
            }
            None if asked => (
                options.tile_config,
                String::new(),
                Some(options.tile_config.filter_size()),
            ),
            None if rule => {
                let voxel = scale::voxel_for_spacing(t.spacing);
                let c = options.tile_config;
                let config = MapConfig::new(
                    voxel,
                    scale::KERNEL_VOXELS * voxel,
                    c.filter_size(),
                    c.prior(),
                    c.mode(),
                )
                .map_err(|e| anyhow::anyhow!("invalid map configuration: {e}"))?;
                (
                    config,
                    format!(
                        "from the points' spacing ≈ {} m: voxel ≈ spacing, ℓ = {} voxels",
                        significant(t.spacing),
                        scale::KERNEL_VOXELS
                    ),
                    None,
                )
            }
            None if options.tile.las.is_none()
                && options.tile.range.is_none()
                && options.tile.altitude.is_none()
                && options.tile.units.is_none()
                && options.tile_config == MapConfig::default() =>
            {
                (
                    options.tile_config,
                    "given: the paper's outdoor configuration".to_string(),
                    None,
                )
            }
            None => (options.tile_config, "given".to_string(), None),
        };
        let flight_note = if flight_given {
            "given".to_string()
        } else {
            format!(
                "from the density: 4 frames of {} points in range, at least {} m",
                options.tile_points,
                significant(scale::scaled_sensor_floor(t.spacing))
            )
        };
        let voxel = config.voxel_size();
        if validate.is_none() {
            let window = scale::window_voxels(range, voxel, config.filter_size());
            if !scale::window_fits(window) {
                bail!("{}", window_error(range, &config));
            }
        }
        let flight_note = format!(
            "LiDAR range {} m, flying {} m above the ground ({flight_note})",
            significant(range),
            significant(altitude),
        );
        let note = if validate.is_some() {
            String::new()
        } else {
            format!(
                "voxel {} m, ℓ = {} m ({map_note}); {flight_note}",
                significant(voxel),
                significant(config.kernel_length()),
            )
        };
        Ok(TileScale {
            flight: (range, altitude),
            config,
            validate,
            note,
            flight_note,
        })
    }

    /// The map configuration to run at, once the frames are encoded: chosen by validation on their
    /// integrated points when the scale is not given ([`crate::eval::scale_search`]; the held-out points are
    /// not read), else the given one. The choice, when there is one, is returned with it.
    pub fn resolve_config(
        &mut self,
        frames: &[crate::eval::methods::EncodedFrame],
        dec: &crate::eval::experiment::Decoding,
        setup: &crate::eval::experiment::ExperimentSettings,
    ) -> Result<(MapConfig, Option<crate::eval::scale_search::Choice>)> {
        let (Some(max_filter), Some(t)) = (self.validate, &self.tile) else {
            return Ok((self.config(), None));
        };
        let candidates = crate::eval::scale_search::candidates(t.spacing, max_filter);
        let range = self.tile_flight.0;
        let choice = crate::eval::scale_search::choose(
            frames,
            &candidates,
            &self.tile_config,
            &dec.decoder,
            dec.classes.len(),
            setup,
            &|c: &MapConfig| {
                scale::window_fits(scale::window_voxels(range, c.voxel_size(), c.filter_size()))
            },
        )?;
        self.tile_config = choice.config;
        self.validate = None;
        self.scale_note = format!("{}; {}", choice.describe(), self.flight_note);
        Ok((choice.config, Some(choice)))
    }
}

/// What [`SceneSource::tile_scale`] decides.
pub(super) struct TileScale {
    pub(super) flight: (f32, f32),
    pub(super) config: MapConfig,
    pub(super) validate: Option<u8>,
    pub(super) note: String,
    pub(super) flight_note: String,
}

/// The line for a voxel size at which the robot's map window cannot hold the sensor's range.
pub(super) fn window_error(range: f32, config: &MapConfig) -> String {
    let voxel = config.voxel_size();
    let window = scale::window_voxels(range, voxel, config.filter_size());
    let max = latentbki::local_map::MAX_WINDOW_VOXELS as f32;
    format!(
        "the LiDAR's range ({} m) spans {window:.0} voxels of {voxel} m, and the device map's window holds at most {max:.0}: give --voxel-size {} or more, or a --range below {} m",
        significant(range),
        significant(scale::preferred_at_least((range + 1.0) / (0.9 * max))),
        significant(0.9 * max * voxel),
    )
}
