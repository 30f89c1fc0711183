//! The furniture of a room, by its type (living room, bedroom, kitchen, bathroom). Apart from the house's
//! shell ([`super::IndoorScene::generate`]: walls, doors, windows) because it is the long, per-room-type
//! part of the scene, and the part one changes to make another kind of room.

use super::{Builder, RoomPlan};

/// Furniture by room type: against walls, or in a free spot, avoiding overlaps and the robot's corridors
/// (the room's midlines, which lead to the doors).
pub(super) fn furnish(b: &mut Builder, r: &RoomPlan, height: f32, outer: (f32, f32)) {
    let mut placed: Vec<([f32; 2], [f32; 2])> = Vec::new();
    let c = [(r.min[0] + r.max[0]) / 2.0, (r.min[1] + r.max[1]) / 2.0];
    // Keep 0.4 m either side of the robot's corridors free: from the centre to the doors, which are in
    // the middle of the interior walls (the walls facing the house's centre).
    let (east, north) = (c[0] < outer.0 / 2.0, c[1] < outer.1 / 2.0);
    let (x0, x1) = if east {
        (c[0], r.max[0])
    } else {
        (r.min[0], c[0])
    };
    let (y0, y1) = if north {
        (c[1], r.max[1])
    } else {
        (r.min[1], c[1])
    };
    placed.push(([x0 - 0.4, c[1] - 0.4], [x1 + 0.4, c[1] + 0.4]));
    placed.push(([c[0] - 0.4, y0 - 0.4], [c[0] + 0.4, y1 + 0.4]));
    let items: &[&str] = match r.kind {
        "living room" => &[
            "sofa", "table", "chair", "chair", "tv", "plant", "lamp", "picture", "shelf", "window",
            "curtain",
        ],
        "bedroom" => &[
            "bed", "cabinet", "lamp", "picture", "shelf", "window", "curtain", "plant",
        ],
        "kitchen" => &[
            "counter", "table", "chair", "chair", "chair", "cabinet", "plant", "window", "picture",
        ],
        _ => &[
            "toilet", "bathtub", "sink", "mirror", "towel", "cabinet", "window", "curtain",
        ],
    };
    for &item in items {
        // (width along the wall, depth from the wall, height, bottom), on a wall or free-standing.
        let (w, d, h, z0, on_wall): (f32, f32, f32, f32, bool) = match item {
            "sofa" => (b.range(1.8, 2.2), 0.9, 0.8, 0.0, true),
            "bed" => (1.4, 1.9, 0.5, 0.0, true),
            "cabinet" => (0.6, 0.5, 0.9, 0.0, true),
            "shelf" => (0.9, 0.35, 1.8, 0.0, true),
            "counter" => (2.0, 0.6, 0.9, 0.0, true),
            "bathtub" => (1.6, 0.75, 0.55, 0.0, true),
            "toilet" => (0.4, 0.65, 0.75, 0.0, true),
            "sink" => (0.6, 0.45, 0.85, 0.0, true),
            "tv" => (1.0, 0.08, 0.6, 1.0, true),
            "picture" => (0.8, 0.03, 0.6, 1.3, true),
            "mirror" => (0.6, 0.03, 0.8, 1.1, true),
            "towel" => (0.5, 0.04, 0.7, 1.0, true),
            "window" => (1.2, 0.04, 1.1, 0.9, true),
            "curtain" => (0.4, 0.08, 2.2, 0.2, true),
            "table" => (1.2, 0.8, 0.75, 0.0, false),
            "chair" => (0.45, 0.45, 0.9, 0.0, false),
            "plant" => (0.4, 0.4, 1.0, 0.0, false),
            _ => (0.3, 0.3, 1.5, 0.0, false), // lamp
        };
        for _attempt in 0..60 {
            let (min, max) = if on_wall {
                let side = (b.rand() * 4.0) as usize % 4;
                // Windows only on outer walls.
                let along_x = side < 2;
                let span = if along_x {
                    (r.min[0], r.max[0])
                } else {
                    (r.min[1], r.max[1])
                };
                if span.1 - span.0 < w + 0.2 {
                    continue;
                }
                let s = b.range(span.0 + 0.1, span.1 - 0.1 - w);
                // Wall-mounted thin things sit proud of the wall by a centimetre so they are seen first.
                let (lo, hi) = match side {
                    0 => ([s, r.min[1] - 0.01], [s + w, r.min[1] + d]),
                    1 => ([s, r.max[1] - d], [s + w, r.max[1] + 0.01]),
                    2 => ([r.min[0] - 0.01, s], [r.min[0] + d, s + w]),
                    _ => ([r.max[0] - d, s], [r.max[0] + 0.01, s + w]),
                };
                if item == "window" {
                    let outer_wall = match side {
                        0 => r.min[1] <= 0.0,
                        1 => r.max[1] >= outer.1,
                        2 => r.min[0] <= 0.0,
                        _ => r.max[0] >= outer.0,
                    };
                    if !outer_wall {
                        continue;
                    }
                }
                (lo, hi)
            } else {
                let x = b.range(r.min[0] + 0.2, r.max[0] - 0.2 - w);
                let y = b.range(r.min[1] + 0.2, r.max[1] - 0.2 - d);
                ([x, y], [x + w, y + d])
            };
            // Thin wall-mounted items above furniture height do not block floor space.
            let blocks_floor = z0 < 0.5;
            if blocks_floor && !b.free(min, max, &placed) {
                continue;
            }
            let inst = b.instance();
            let top: f32 = (z0 + h).min(height - 0.05);
            match item {
                "table" => {
                    b.push(
                        [min[0], min[1], 0.70],
                        [max[0], max[1], 0.75],
                        "table",
                        inst,
                    );
                    for (lx, ly) in [
                        (min[0], min[1]),
                        (max[0] - 0.05, min[1]),
                        (min[0], max[1] - 0.05),
                        (max[0] - 0.05, max[1] - 0.05),
                    ] {
                        b.push([lx, ly, 0.0], [lx + 0.05, ly + 0.05, 0.70], "table", inst);
                    }
                }
                "chair" => {
                    b.push(
                        [min[0], min[1], 0.42],
                        [max[0], max[1], 0.47],
                        "chair",
                        inst,
                    );
                    b.push([min[0], min[1], 0.0], [max[0], max[1], 0.42], "chair", inst);
                    b.push(
                        [min[0], max[1] - 0.05, 0.47],
                        [max[0], max[1], 0.9],
                        "chair",
                        inst,
                    );
                }
                "bed" | "sofa" => {
                    b.push([min[0], min[1], 0.0], [max[0], max[1], top], item, inst);
                    let ci = b.instance();
                    let cx = (min[0] + max[0]) / 2.0;
                    let cy = (min[1] + max[1]) / 2.0;
                    b.push(
                        [cx - 0.3, cy - 0.2, top],
                        [cx + 0.3, cy + 0.2, top + 0.15],
                        "cushion",
                        ci,
                    );
                }
                "counter" => {
                    b.push(
                        [min[0], min[1], 0.0],
                        [max[0], max[1], top],
                        "counter",
                        inst,
                    );
                    let si = b.instance();
                    let cx = (min[0] + max[0]) / 2.0;
                    let cy = (min[1] + max[1]) / 2.0;
                    b.push(
                        [cx - 0.25, cy - 0.2, top],
                        [cx + 0.25, cy + 0.2, top + 0.12],
                        "sink",
                        si,
                    );
                }
                _ => b.push([min[0], min[1], z0], [max[0], max[1], top], item, inst),
            }
            if blocks_floor {
                placed.push((min, max));
            }
            break;
        }
    }
}
