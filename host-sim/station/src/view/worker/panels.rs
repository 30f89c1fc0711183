//! The view's small topics: the map's centre frame (so the camera opens on the map), the legend of the
//! classes' colours and the query, and the links' status.

use super::*;

impl<const D: usize, const K: usize> Worker<D, K> {
    /// Send the centre frame when it moved (checked at most every [`CENTRE_EVERY`], or at a full scene).
    pub(super) fn centre(&mut self, now: bool) {
        if !now
            && self
                .last_frame
                .as_ref()
                .is_some_and(|f| f.0.elapsed() < CENTRE_EVERY)
        {
            return;
        }
        let Some(c) = self.scene.as_ref().and_then(DecodedMap::centre) else {
            return;
        };
        let moved = self.last_frame.as_ref().is_none_or(|f| {
            let d: f32 = (0..3).map(|i| (f.1[i] - c[i]).powi(2)).sum();
            d.sqrt() >= CENTRE_MOVE
        });
        if !moved {
            if let Some(f) = &mut self.last_frame {
                f.0 = Instant::now();
            }
            return;
        }
        let msg = FrameTransforms {
            transforms: vec![FrameTransform {
                timestamp: Some(Timestamp::now()),
                parent_frame_id: crate::view::scene::FRAME.into(),
                child_frame_id: CENTRE_FRAME.into(),
                translation: Some(Vector3 {
                    x: f64::from(c[0]),
                    y: f64::from(c[1]),
                    z: f64::from(c[2]),
                }),
                rotation: Some(Quaternion {
                    x: 0.0,
                    y: 0.0,
                    z: 0.0,
                    w: 1.0,
                }),
            }],
        };
        let mut bytes = Vec::new();
        foxglove::Encode::encode(&msg, &mut bytes).expect("a Vec grows");
        self.send_live(|ch| &ch.frame, &bytes, None);
        self.last_frame = Some((Instant::now(), c, bytes));
    }

    /// The legend: each class's name, colour and voxels; the phrase in force.
    pub(super) fn legend(&self) -> Vec<u8> {
        let counts = match (&self.scene, &self.vocabulary) {
            (Some(s), Some(v)) => s.class_counts(v.names.len()),
            (_, Some(v)) => vec![0; v.names.len()],
            _ => Vec::new(),
        };
        let hex = |[r, g, b]: [u8; 3]| format!("#{r:02x}{g:02x}{b:02x}");
        let classes: Vec<_> = self.vocabulary.as_ref().map_or(Vec::new(), |v| {
            v.names
                .iter()
                .enumerate()
                .map(|(i, n)| {
                    let rgb = self
                        .scene
                        .as_ref()
                        .map_or_else(|| class_colour(n, i), |s| s.class_colour(i));
                    serde_json::json!({
                        "class": n, "colour": hex(rgb), "voxels": counts[i], "index": i, "rgb": rgb,
                    })
                })
                .collect()
        });
        let classified: usize = counts.iter().sum();
        let all = self.scene.as_ref().map_or(0, DecodedMap::len);
        serde_json::to_vec(&serde_json::json!({
            "classes": classes,
            "undecoded": {"colour": "#808080", "voxels": all - classified.min(all)},
            "error": self.mismatch,
            "query": self.phrase.0,
            "query_error": self.phrase.1,
            "robots": "palette by robot id (the class palette); white: several robots",
            "heat": "viridis over the cosine scores (2nd to 98th percentile) when the phrase was set; exact score in metadata",
            "uncertainty": "viridis over log E-optimality (authors' t_var, lambda > 2; 2nd to 98th percentile); grey: undefined",
        }))
        .expect("JSON")
    }

    pub(super) fn status(
        &self,
        s: &ReceiveStats,
        sessions: &BTreeMap<(u16, u32), SessionState>,
    ) -> Vec<u8> {
        let sessions: Vec<_> = sessions
            .iter()
            .map(|((robot, session), st)| {
                serde_json::json!({
                    "robot": robot, "session": session, "received": st.seq.received,
                    "lost": st.seq.lost, "late": st.seq.late,
                    "robot_frames_sent": st.link.map(|l| l.frames_sent),
                    "robot_refused": st.link.map(|l| l.refused),
                })
            })
            .collect();
        let r = &s.refused;
        let d = &s.decoder;
        serde_json::to_vec(&serde_json::json!({
            "frames": s.frames, "merged": s.merged, "live": s.updated, "ignored": s.ignored,
            "lost": s.lost, "late": s.late, "duplicates": r.duplicate_frames,
            "refused": d.crc_errors + d.cobs_errors + d.too_short + d.overflows + r.version
                + r.malformed + r.wrong_config + r.invalid_voxel + r.too_old,
            "viewer_clients_refused": guard::refused() - self.refused_at_start,
            "sessions": sessions,
        }))
        .expect("JSON")
    }
}
