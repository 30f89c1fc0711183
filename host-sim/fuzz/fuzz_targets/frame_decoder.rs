//! Any bytes, in any chunking, into the frame decoder and the message parser: never a panic, and every
//! accepted frame's summaries either decode or are refused.
#![no_main]

use latentbki::frame::{Feed, FrameDecoder};
use latentbki::wire::{parse_body, Message, SummaryCodec};
use libfuzzer_sys::fuzz_target;

/// A lead band of 8 components at 3 bits, the rest at 3 bits growing with the count.
const LEAD_BAND: SummaryCodec = SummaryCodec {
    mean_bits: 3,
    psi_blocks: 2,
    mean_bits_growth: 3,
    lead: 8,
    lead_bits: 3,
    rice: false,
};

fuzz_target!(|data: &[u8]| {
    let Some((&chunk, bytes)) = data.split_first() else {
        return;
    };
    let chunk = usize::from(chunk).max(1);
    let mut dec = FrameDecoder::<512>::new();
    for c in bytes.chunks(chunk) {
        let mut input = c;
        loop {
            match dec.feed(input) {
                Feed::NeedMore => break,
                Feed::Error { rest, .. } => input = rest,
                Feed::Frame { body, rest } => {
                    if let Ok((_, Message::Voxels(batch))) = parse_body(body) {
                        for codec in [
                            SummaryCodec::DEFAULT,
                            SummaryCodec {
                                mean_bits: 8,
                                psi_blocks: 64,
                                mean_bits_growth: 0,
                                lead: 0,
                                lead_bits: 0,
                                rice: false,
                            },
                            // Rice-coded heads and means, one band.
                            SummaryCodec {
                                psi_blocks: 3,
                                rice: true,
                                ..SummaryCodec::DEFAULT
                            },
                            // A lead band, packed (the demo's before Rice codes) and Rice-coded.
                            LEAD_BAND,
                            SummaryCodec {
                                rice: true,
                                ..LEAD_BAND
                            },
                            // The map's own codes, verbatim.
                            SummaryCodec::STORED,
                        ] {
                            for s in batch.iter::<64>(codec) {
                                if let Ok(s) = s {
                                    // A stamped summary (forgetting) carries a weight in (0, 2^24].
                                    let weight_ok = match s.time {
                                        Some(_) => s.obs.count > 0.0,
                                        None => s.obs.count >= 1.0,
                                    };
                                    assert!(s.key.in_range() && weight_ok && s.obs.is_valid());
                                }
                            }
                        }
                    }
                    input = rest;
                }
            }
        }
    }
    // The parser on raw bytes too (no CRC in the way).
    let _ = parse_body(bytes);
});
