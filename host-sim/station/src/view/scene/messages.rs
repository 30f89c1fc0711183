//! A scene's layers as Foxglove messages: each block's entity of cubes (its values in the metadata), the
//! update of the blocks that changed, and the full scene a late joiner gets, joined from the entities
//! encoded once and kept.

use super::*;

impl<const D: usize, const K: usize> DecodedMap<D, K> {
    /// A block's entity on a layer (None if the block is empty).
    pub fn entity(&self, layer: Layer, block: BlockKey, time: Timestamp) -> Option<SceneEntity> {
        let keys = self.blocks.get(&block)?;
        let side = f64::from(self.voxel_size);
        let mut cubes = Vec::with_capacity(keys.len());
        let mut values = String::with_capacity(keys.len() * 6);
        let mut positions = String::with_capacity(keys.len() * 12);
        for (i, k) in keys.iter().enumerate() {
            let row = &self.rows[k];
            let c = k.centroid(self.voxel_size);
            let [r, g, b] = self.colour(layer, row);
            cubes.push(CubePrimitive {
                pose: Some(Pose {
                    position: Some(Vector3 {
                        x: f64::from(c[0]),
                        y: f64::from(c[1]),
                        z: f64::from(c[2]),
                    }),
                    orientation: Some(Quaternion {
                        x: 0.0,
                        y: 0.0,
                        z: 0.0,
                        w: 1.0,
                    }),
                }),
                size: Some(Vector3 {
                    x: side,
                    y: side,
                    z: side,
                }),
                color: Some(Color {
                    r: f64::from(r) / 255.0,
                    g: f64::from(g) / 255.0,
                    b: f64::from(b) / 255.0,
                    a: 1.0,
                }),
            });
            if i > 0 {
                values.push(',');
                positions.push(',');
            }
            Self::value(layer, row, &mut values);
            let _ = write!(positions, "{} {} {}", k.x, k.y, k.z);
        }
        Some(SceneEntity {
            timestamp: Some(time),
            frame_id: FRAME.into(),
            id: block.id(),
            metadata: vec![
                KeyValuePair {
                    key: "voxels".into(),
                    value: positions,
                },
                KeyValuePair {
                    key: layer.key().into(),
                    value: values,
                },
            ],
            cubes,
            ..Default::default()
        })
    }

    /// The entities of `blocks` on a layer; a block that emptied is deleted.
    pub fn update_message(
        &self,
        layer: Layer,
        blocks: &BTreeSet<BlockKey>,
        time: Timestamp,
    ) -> SceneUpdate {
        let mut msg = SceneUpdate::default();
        for &b in blocks {
            match self.entity(layer, b, time) {
                Some(e) => msg.entities.push(e),
                None => msg.deletions.push(SceneEntityDeletion {
                    timestamp: Some(time),
                    r#type: scene_entity_deletion::Type::MatchingId as i32,
                    id: b.id(),
                }),
            }
        }
        msg
    }

    /// The whole layer: everything shown before is deleted, then every block.
    pub fn full_message(&self, layer: Layer, time: Timestamp) -> SceneUpdate {
        let mut msg = SceneUpdate {
            deletions: vec![SceneEntityDeletion {
                timestamp: Some(time),
                r#type: scene_entity_deletion::Type::All as i32,
                id: String::new(),
            }],
            entities: Vec::with_capacity(self.blocks.len()),
        };
        for &b in self.blocks.keys() {
            msg.entities.extend(self.entity(layer, b, time));
        }
        msg
    }
}

impl<const D: usize, const K: usize> DecodedMap<D, K> {
    /// [`Self::update_message`] as it goes on the wire, the blocks' entities built once and kept for
    /// later full scenes.
    pub fn update_bytes(
        &mut self,
        layer: Layer,
        blocks: &BTreeSet<BlockKey>,
        time: Timestamp,
    ) -> Vec<u8> {
        let deletions = blocks
            .iter()
            .filter(|b| !self.blocks.contains_key(b))
            .map(|b| SceneEntityDeletion {
                timestamp: Some(time),
                r#type: scene_entity_deletion::Type::MatchingId as i32,
                id: b.id(),
            })
            .collect();
        let kept = blocks.iter().filter(|b| self.blocks.contains_key(b));
        self.joined(layer, deletions, kept.copied().collect(), time)
    }

    /// [`Self::full_message`] as it goes on the wire: the cached entities joined, building (and
    /// keeping) only those of blocks that changed since they were last built.
    pub fn full_bytes(&mut self, layer: Layer, time: Timestamp) -> Vec<u8> {
        let all = vec![SceneEntityDeletion {
            timestamp: Some(time),
            r#type: scene_entity_deletion::Type::All as i32,
            id: String::new(),
        }];
        let blocks = self.blocks.keys().copied().collect();
        self.joined(layer, all, blocks, time)
    }

    /// `deletions` encoded, then each of `blocks`' entities from the cache (built if missing).
    fn joined(
        &mut self,
        layer: Layer,
        deletions: Vec<SceneEntityDeletion>,
        blocks: Vec<BlockKey>,
        time: Timestamp,
    ) -> Vec<u8> {
        let mut cache = std::mem::take(&mut self.encoded[layer as usize]);
        let mut out = encode(&SceneUpdate {
            deletions,
            entities: Vec::new(),
        });
        out.reserve(cache.values().map(Vec::len).sum());
        for b in blocks {
            let bytes = cache.entry(b).or_insert_with(|| {
                encode(&SceneUpdate {
                    deletions: Vec::new(),
                    entities: self.entity(layer, b, time).into_iter().collect(),
                })
            });
            out.extend_from_slice(bytes);
        }
        self.encoded[layer as usize] = cache;
        out
    }
}

/// A message as it goes on the wire (protobuf).
pub fn encode(msg: &SceneUpdate) -> Vec<u8> {
    use foxglove::Encode;
    let mut buf = Vec::with_capacity(msg.encoded_len().unwrap_or(0));
    msg.encode(&mut buf).expect("a Vec grows");
    buf
}
