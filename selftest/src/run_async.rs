//! [`run`](crate::run) over `embedded-io-async` (feature `async`): the same scenario, the same calls in the
//! same order — integrate, a budgeted tick, the loopback's acknowledgements read back, a drain that waits
//! for them — with the writes and reads awaited. So an embassy firmware's UART carries the bytes of the
//! blocking host twin (`boards/embassy-mps2-an386`, `host-sim/tests/stream_embassy.rs`).

use crate::loopback::Loopback;
use crate::run::{integrate_frame, Chunk, FrameReport, Probe, RunError, RunReport};
use crate::scenarios::Scenario;
use crate::SELF_TEST_ROBOT;
use latentbki::forget::MapClock;
use latentbki::local_map::{Counters, LocalMap};
use latentbki::{DrainError, Mapper};

/// [`run`](crate::run) with the UART and the back channel async.
pub async fn run_async<
    const D: usize,
    const CAP: usize,
    const P: usize,
    const QB: usize,
    const N: usize,
    const H: usize,
    const K: usize,
    W,
    M,
    C: MapClock,
>(
    scenario: &Scenario,
    mapper: &mut Mapper<D, CAP, P, QB, N, H, C>,
    chunk: &mut Chunk<D, K>,
    w: &mut W,
    probe: &mut M,
    mut on_frame: impl FnMut(u32, &FrameReport, &LocalMap<D, CAP, P, H, C>),
) -> Result<RunReport, RunError<W::Error>>
where
    W: embedded_io_async::Write,
    M: Probe,
{
    let config = scenario.map_config().map_err(RunError::Config)?;
    let map = mapper.map();
    let fresh = map.config() == &config && map.is_empty() && map.counters() == Counters::default();
    if !fresh || !mapper.encoder().is_configured() || mapper.encoder().next_seq() != 0 {
        return Err(RunError::NotConfigured);
    }
    let mut report = RunReport::default();
    let mut back = Loopback::new();
    let (robot, session) = (SELF_TEST_ROBOT, scenario.session);
    for frame in 0..scenario.frames {
        mapper.set_time(frame);
        let f = integrate_frame(
            scenario.scene,
            frame,
            scenario.int8_scale,
            mapper,
            chunk,
            probe,
        );
        report.points += f.points;
        report.integrated += f.integrated;
        report.peak_voxels = report.peak_voxels.max(mapper.map().len() as u32);
        on_frame(frame, &f, mapper.map());
        mapper
            .tick_async(w, scenario.tick_budget)
            .await
            .map_err(|latentbki::frame::TickError::Write(e, _)| RunError::Write(e))?;
        back.acknowledge_all(robot, session, mapper.encoder().next_seq());
        let Ok(_) = mapper.poll_acks_async(&mut back).await;
    }
    let before = mapper.map().counters().evicted;
    loop {
        let done = match mapper.drain_async(w).await {
            Ok(_) => true,
            Err(DrainError::Write(e)) => return Err(RunError::Write(e)),
            // Stuck (or a reason a later version adds): acknowledgements may free the re-send buffer.
            Err(_) => false,
        };
        back.acknowledge_all(robot, session, mapper.encoder().next_seq());
        let Ok(read) = mapper.poll_acks_async(&mut back).await;
        if done {
            break;
        }
        if read == 0 {
            return Err(RunError::Stuck);
        }
    }
    if !mapper.is_drained() {
        return Err(RunError::Stuck);
    }
    report.flushed = mapper.map().counters().evicted.wrapping_sub(before);
    report.rejections = mapper.map().rejections();
    report.counters = mapper.map().counters();
    report.link = mapper.encoder().stats();
    Ok(report)
}
