//! Any bytes, in any chunking, on the robot's back channel: never a panic, nothing trusted that is not an
//! acknowledgement of this robot's session, and the robot's kept frames only ever shrink by what such
//! acknowledgements name.
#![no_main]

use latentbki::frame::{AckReader, EncoderSettings, FrameEncoder, Resend};
use latentbki::wire::{SessionConfig, SummaryCodec, NO_FEATURE_SPACE};
use latentbki::{key::VoxelKey, obs::ObsStats, sink::EvictionSink, MapConfig};
use libfuzzer_sys::fuzz_target;

const D: usize = 8;

fuzz_target!(|data: &[u8]| {
    let Some((&chunk, bytes)) = data.split_first() else {
        return;
    };
    let chunk = usize::from(chunk).max(1);
    let config = SessionConfig::new(
        &MapConfig::default(),
        D,
        SummaryCodec::DEFAULT,
        NO_FEATURE_SPACE,
    );
    let settings = EncoderSettings::new(1, 2).with_resend(Resend::new(1500, 4));
    let mut robot = FrameEncoder::<D, 3000, 256>::new(config, settings).unwrap();
    let obs = ObsStats {
        count: 3.0,
        mean: [0.5; D],
        scatter: [0.1; D],
    };
    for i in 0..20 {
        let _ = robot.evict(latentbki::frame::live(
            VoxelKey::new(i, 0, 0),
            &obs,
            i as u32,
        ));
    }
    let mut sink = [0u8; 4096];
    let mut out: &mut [u8] = &mut sink;
    robot.tick(&mut out, 4096, core::iter::empty()).unwrap();
    let kept = robot.unacknowledged();
    assert!(kept > 0);
    let mut reader = AckReader::new();
    for c in bytes.chunks(chunk) {
        reader.feed(c, 1, 2, |ack| {
            assert_eq!(
                (ack.robot, ack.session),
                (1, 2),
                "a foreign acknowledgement was accepted"
            );
            assert_eq!(ack.received & 1, 1);
            robot.acknowledge(&ack);
        });
        assert!(robot.unacknowledged() <= kept);
    }
    let s = reader.stats();
    assert!(s.accepted as usize + s.refused() as usize <= bytes.len());
});
