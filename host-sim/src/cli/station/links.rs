//! Where a base station's bytes come from, and where its acknowledgements go: serial ports, ptys and other
//! terminals (read and written), recordings (read one after another), stdin (and stdout for a gateway's
//! `--stdio`) and a TCP listener whose every connection is a link.
//!
//! Every link is read on its own thread and sends its bytes, tagged with its [`LinkId`], into one channel
//! the receiving loop drains (module `receive`); every link with a back channel has its own writer
//! thread fed through a short queue, so a link that stalls, dies or floods the line with garbage holds up
//! only itself: the loop never blocks on a link, and an acknowledgement a stalled link cannot take is
//! dropped and counted (the next one repeats it: it carries the session's whole state).

use crate::base_station::LinkId;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::mpsc::{sync_channel, SyncSender, TrySendError};
use std::sync::Arc;
use std::time::Duration;

/// Acknowledgement bytes for one link's writer thread.
pub type AckSender = SyncSender<Vec<u8>>;

/// What the links report to the receiving loop.
pub enum Event {
    /// A link opened; its acknowledgements go to `acks` (None: a recording or a one-way input).
    Opened {
        /// Its id.
        link: LinkId,
        /// What it is (a port, a path, a peer address).
        name: String,
        /// Its back channel.
        acks: Option<AckSender>,
    },
    /// Bytes from a link.
    Bytes(LinkId, Vec<u8>),
    /// A link ended: its input ended (`None`) or failed.
    Closed {
        /// Its id.
        link: LinkId,
        /// Why, if it failed.
        error: Option<String>,
    },
}

/// The channel every link's reader sends into (bounded: a reader waits while the loop catches up).
pub type Events = std::sync::mpsc::Receiver<Event>;

/// Hands out link ids in the order links open.
#[derive(Clone, Default)]
pub struct LinkIds(Arc<AtomicU32>);

impl LinkIds {
    /// The next id.
    pub fn next(&self) -> LinkId {
        LinkId(self.0.fetch_add(1, Ordering::Relaxed))
    }
}

/// Acknowledgements queued per link before they are dropped (a link that does not take them).
const ACK_QUEUE: usize = 16;

/// Start a writer thread for a link's back channel.
pub fn spawn_writer(mut w: Box<dyn Write + Send>) -> AckSender {
    let (tx, rx) = sync_channel::<Vec<u8>>(ACK_QUEUE);
    std::thread::spawn(move || {
        for bytes in rx {
            if w.write_all(&bytes).and_then(|()| w.flush()).is_err() {
                return; // the back channel died: later acknowledgements are dropped by the loop
            }
        }
    });
    tx
}

/// Queue bytes for a link's writer without waiting. Returns false if they were dropped (its queue is full:
/// the link does not take what it is sent).
pub fn try_send(tx: &AckSender, bytes: Vec<u8>) -> bool {
    match tx.try_send(bytes) {
        Ok(()) => true,
        Err(TrySendError::Full(_)) => false,
        Err(TrySendError::Disconnected(_)) => false,
    }
}

/// Read `source` as link `link` until it ends or fails (chunks of up to 64 KiB), then report it closed.
/// Returns false if the loop is gone.
fn pump_reader(events: &SyncSender<Event>, link: LinkId, source: &mut dyn Read) -> bool {
    let mut buf = vec![0u8; 64 * 1024];
    let error = loop {
        match source.read(&mut buf) {
            Ok(0) => break None,
            Ok(n) => {
                if events.send(Event::Bytes(link, buf[..n].to_vec())).is_err() {
                    return false;
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::TimedOut
                        | std::io::ErrorKind::Interrupted
                        | std::io::ErrorKind::WouldBlock
                ) => {}
            Err(e) => break Some(e.to_string()),
        }
    };
    events.send(Event::Closed { link, error }).is_ok()
}

/// A link read and, when it has a back channel, written.
pub struct Source {
    /// What it is.
    pub name: String,
    /// Its bytes.
    pub read: Box<dyn Read + Send>,
    /// Its back channel.
    pub write: Option<Box<dyn Write + Send>>,
}

/// Read one live link on its own thread.
pub fn spawn_link(events: SyncSender<Event>, ids: &LinkIds, source: Source) {
    let link = ids.next();
    std::thread::spawn(move || {
        let Source {
            name,
            mut read,
            write,
        } = source;
        let acks = write.map(spawn_writer);
        if events.send(Event::Opened { link, name, acks }).is_ok() {
            pump_reader(&events, link, &mut read);
        }
    });
}

/// Read recordings one after another on one thread, each its own link (a frame cut at the end of one file
/// never glues to the next file's bytes): the same as feeding them in this order.
pub fn spawn_files(events: SyncSender<Event>, ids: &LinkIds, files: Vec<(PathBuf, std::fs::File)>) {
    let links: Vec<LinkId> = files.iter().map(|_| ids.next()).collect();
    std::thread::spawn(move || {
        for ((path, mut file), link) in files.into_iter().zip(links) {
            let name = path.display().to_string();
            let opened = Event::Opened {
                link,
                name,
                acks: None,
            };
            if events.send(opened).is_err() || !pump_reader(&events, link, &mut file) {
                return;
            }
        }
    });
}

/// Accept TCP connections on `listener`, each a link read and acknowledged on its own threads (a gateway
/// forwarding a robot's serial bytes).
pub fn spawn_listener(events: SyncSender<Event>, ids: LinkIds, listener: TcpListener) {
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(stream) = stream else { continue };
            let _ = stream.set_nodelay(true);
            let name = stream
                .peer_addr()
                .map_or_else(|_| "tcp".to_string(), |a| format!("tcp {a}"));
            let write = stream
                .try_clone()
                .ok()
                .map(|w| Box::new(w) as Box<dyn Write + Send>);
            let source = Source {
                name,
                read: Box::new(stream),
                write,
            };
            spawn_link(events.clone(), &ids, source);
        }
    });
}

/// [`spawn_listener`] for connections that get no acknowledgements (`--no-acks`).
pub fn spawn_listener_one_way(events: SyncSender<Event>, ids: LinkIds, listener: TcpListener) {
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(stream) = stream else { continue };
            let name = stream
                .peer_addr()
                .map_or_else(|_| "tcp".to_string(), |a| format!("tcp {a}"));
            let source = Source {
                name,
                read: Box::new(stream),
                write: None,
            };
            spawn_link(events.clone(), &ids, source);
        }
    });
}

/// A serial port or another terminal (a pty) at `baud`, in raw mode, read and written.
pub fn open_terminal(path: &str, baud: u32) -> std::io::Result<Source> {
    let port = serialport::new(path, baud)
        .timeout(Duration::from_millis(200))
        .open()
        .map_err(std::io::Error::other)?;
    let write = port.try_clone().map_err(std::io::Error::other)?;
    Ok(Source {
        name: path.to_string(),
        read: Box::new(port),
        write: Some(Box::new(write)),
    })
}

/// `--listen`'s default: this machine only.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:7707";

/// Bind the TCP listener (a clear error when the address is taken).
pub fn bind(addr: SocketAddr) -> std::io::Result<TcpListener> {
    TcpListener::bind(addr)
}
