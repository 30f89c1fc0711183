//! Whether a scene's run can say anything: enough points to fit the PCA and to test, and a hint when the
//! held-out points fall where no integrated point reached.

use super::*;

impl SceneSource {
    /// A run needs more than D points in the training sequence (to fit the D-component PCA) and in the
    /// test sequence: otherwise stop with one line that says what to change.
    pub fn check_enough(&self, train: &Sequence, test: &Sequence) -> Result<()> {
        let need = crate::eval::methods::D + 1;
        let seen = train.points().min(test.points());
        if seen >= need {
            return Ok(());
        }
        let frames = test.frames.len();
        match (self.scene, &self.tile) {
            (SceneKind::Tile, Some(t)) if t.points.len() < need => {
                let advice = if (t.points.len() as u64) < t.file_points {
                    "raise --max-points, or use a larger tile"
                } else {
                    "use a larger tile"
                };
                bail!(
                    "too few points: {} holds {} usable points and the {}-component feature PCA needs at least {need}: {advice}",
                    self.title(),
                    t.points.len(),
                    crate::eval::methods::D,
                )
            }
            (SceneKind::Tile, Some(t)) => {
                let (lo, hi) = t.bounds;
                let (range, altitude) = self.tile_flight;
                let advice = if altitude >= range {
                    "lower --altitude below the range, or raise --range"
                } else {
                    "raise --range, --points or --frames"
                };
                bail!(
                    "too sparse: the robot's LiDAR saw {seen} points in {frames} frames over {} ({:.0} × {:.0} m, {:.1} points/m², range {:.1} m, flying {:.1} m above the ground), and the {}-component feature PCA needs at least {need}: {advice}",
                    self.title(),
                    hi[0] - lo[0],
                    hi[1] - lo[1],
                    t.points.len() as f32 / t.area().max(1e-6),
                    range,
                    altitude,
                    crate::eval::methods::D,
                )
            }
            _ => bail!(
                "too sparse: the camera saw {seen} points in {frames} frames, and the {}-component feature PCA needs at least {need}: raise --pixels",
                crate::eval::methods::D
            ),
        }
    }

    /// When the LatentBKI map (filter size `f`) left more than 20 % of the held-out tile points in voxels
    /// no integrated point reached, one line that says what to change: voxels about the size of the tile's
    /// point spacing (the kernel length kept at five voxels, the paper's ratio), or more frames.
    pub fn coverage_hint(
        &self,
        results: &[MethodResult],
        f: u8,
        config: &MapConfig,
    ) -> Option<String> {
        let (SceneKind::Tile, Some(t)) = (self.scene, &self.tile) else {
            return None;
        };
        let r = results.iter().find(|r| r.method == Method::LatentBki(f))?;
        let unknown = r.confusion.unknown() as f64 / r.confusion.total().max(1) as f64;
        if unknown <= 0.2 {
            return None;
        }
        let spacing = (t.area() as f64 / t.points.len().max(1) as f64).sqrt();
        let voxel = config.voxel_size();
        let advice = if spacing > 1.5 * f64::from(voxel) {
            let v = (spacing * 20.0).round() / 20.0;
            format!(
                "try --voxel-size {v:.2} --kernel-length {:.2} (about the spacing), or more --frames",
                5.0 * v
            )
        } else {
            "give more --frames or --points".to_string()
        };
        Some(format!(
            "hint: {:.0} % of the held-out points fell in voxels no integrated point reached; the tile's points are ≈ {spacing:.2} m apart and the voxels {voxel} m: {advice}",
            100.0 * unknown
        ))
    }
}
