//! The heat layer once more, as one `foxglove.PointCloud`, so that a phrase typed in the viewer repaints fast.
//!
//! A new phrase changes every voxel's score, so the cube layer (`/map/heat`) goes out whole: ≈ 120 B per
//! voxel (pose, size, colour, metadata; 4.4 MB for the demo's 35,903 voxels), which a viewer decodes into
//! one object per cube before it can draw. A point cloud is 20 B per voxel in one packed buffer the viewer
//! reads as typed arrays and draws in one call — the same colours (the [`Layer::Heat`] ramp, as `red`,
//! `green`, `blue`, `alpha` fields, which Foxglove and Lichtblick paint directly) and the exact score
//! (`score`, NaN without a query) for inspection. It cannot update a part of itself, so it goes out whole,
//! at most once a second as the map grows and at once for a new phrase; the committed layout's top-down
//! heat panel shows it (as squares), the cube layer stays for 3D.

use super::scene::{DecodedMap, Layer, FRAME};
use foxglove::messages::{
    packed_element_field::NumericType, PackedElementField, PointCloud, Pose, Quaternion, Timestamp,
    Vector3,
};

/// The topic.
pub const HEAT_CLOUD_TOPIC: &str = "/map/heat_cloud";

/// Bytes per point: x, y, z (f32), red, green, blue, alpha (u8), score (f32).
const STRIDE: u32 = 20;

/// The scene's heat as one point cloud (voxel centres, frame [`FRAME`]).
pub fn heat_cloud<const D: usize, const K: usize>(
    scene: &DecodedMap<D, K>,
    time: Timestamp,
) -> PointCloud {
    let field = |name: &str, offset: u32, ty: NumericType| PackedElementField {
        name: name.into(),
        offset,
        r#type: ty as i32,
    };
    let mut data = Vec::with_capacity(scene.len() * STRIDE as usize);
    for (k, row) in scene.voxels() {
        let c = k.centroid(scene.voxel_size());
        for v in c {
            data.extend_from_slice(&v.to_le_bytes());
        }
        data.extend_from_slice(&scene.colour(Layer::Heat, row));
        data.push(255);
        data.extend_from_slice(&row.heat.unwrap_or(f32::NAN).to_le_bytes());
    }
    PointCloud {
        timestamp: Some(time),
        frame_id: FRAME.into(),
        pose: Some(Pose {
            position: Some(Vector3::default()),
            orientation: Some(Quaternion {
                x: 0.0,
                y: 0.0,
                z: 0.0,
                w: 1.0,
            }),
        }),
        point_stride: STRIDE,
        fields: vec![
            field("x", 0, NumericType::Float32),
            field("y", 4, NumericType::Float32),
            field("z", 8, NumericType::Float32),
            field("red", 12, NumericType::Uint8),
            field("green", 13, NumericType::Uint8),
            field("blue", 14, NumericType::Uint8),
            field("alpha", 15, NumericType::Uint8),
            field("score", 16, NumericType::Float32),
        ],
        data: data.into(),
    }
}

/// [`heat_cloud`] as it goes on the wire.
pub fn heat_cloud_bytes<const D: usize, const K: usize>(
    scene: &DecodedMap<D, K>,
    time: Timestamp,
) -> Vec<u8> {
    let msg = heat_cloud(scene, time);
    let mut buf = Vec::with_capacity(msg.data.len() + 256);
    foxglove::Encode::encode(&msg, &mut buf).expect("a Vec grows");
    buf
}
