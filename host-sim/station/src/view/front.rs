//! The live view's front door: every Foxglove-protocol client connects, whichever name of the protocol it
//! offers.
//!
//! Foxglove's SDK negotiates only `foxglove.sdk.v1` (and `.v1.1`) and answers any other offer with HTTP 400,
//! but the published protocol's name is `foxglove.websocket.v1`, and older Foxglove Studio builds,
//! Lichtblick before v1.22 and tools written against the published spec offer only that one. The two are
//! the same protocol under two names (Foxglove's stated position; Lichtblick v1.22 added the new name
//! beside the old one). The SDK's handshake cannot be configured, so this front listens where the user
//! asked, and for each connection reads the HTTP upgrade request, renames a lone classic offer to
//! `foxglove.sdk.v1` for the SDK's server (bound to an ephemeral loopback port), renames the accepted
//! protocol back in the reply, and from then on copies bytes both ways untouched. A client that offers a
//! name the SDK knows is passed through as it is. Two threads per client; the SDK's per-client queue
//! still bounds what a client that does not read can cost (the front holds one 8 KiB buffer per
//! direction).

use std::collections::HashMap;
use std::io::{self, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::Duration;

/// The published protocol's name.
pub const CLASSIC: &str = "foxglove.websocket.v1";
/// The name Foxglove's SDK negotiates.
pub const SDK: &str = "foxglove.sdk.v1";
/// Names the SDK accepts as they are.
const SDK_NAMES: [&str; 2] = [SDK, "foxglove.sdk.v1.1"];
/// Longest HTTP head accepted (request or reply).
const MAX_HEAD: usize = 64 * 1024;
/// How long a client may take to send its upgrade request.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// Open connections, by number: both sockets, to close them at shutdown.
type Open = Arc<Mutex<HashMap<u64, [TcpStream; 2]>>>;

/// The listening front and its connections.
pub struct Front {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    open: Open,
    accept: Option<JoinHandle<()>>,
}

impl Front {
    /// Listen on `listen` and hand each connection to the SDK's server at `backend`.
    pub fn start(listen: SocketAddr, backend: SocketAddr) -> io::Result<Self> {
        let listener = TcpListener::bind(listen)?;
        let addr = listener.local_addr()?;
        let stop = Arc::new(AtomicBool::new(false));
        let open: Open = Arc::default();
        let (s, o) = (stop.clone(), open.clone());
        let accept = std::thread::Builder::new()
            .name("view-front".into())
            .spawn(move || accept_loop(listener, backend, s, o))?;
        Ok(Self {
            addr,
            stop,
            open,
            accept: Some(accept),
        })
    }

    /// Where the front listens (the port a client connects to).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// Stop listening and close every connection.
    pub fn stop(mut self) {
        self.close();
    }

    fn close(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        // Wake the blocking accept with a connection of our own.
        let mut wake = self.addr;
        if wake.ip().is_unspecified() {
            wake.set_ip(match wake {
                SocketAddr::V4(_) => [127, 0, 0, 1].into(),
                SocketAddr::V6(_) => std::net::Ipv6Addr::LOCALHOST.into(),
            });
        }
        let _ = TcpStream::connect_timeout(&wake, Duration::from_secs(1));
        if let Some(t) = self.accept.take() {
            let _ = t.join();
        }
        for [a, b] in self
            .open
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .drain()
            .map(|(_, s)| s)
        {
            let _ = a.shutdown(Shutdown::Both);
            let _ = b.shutdown(Shutdown::Both);
        }
    }
}

impl Drop for Front {
    fn drop(&mut self) {
        if self.accept.is_some() {
            self.close();
        }
    }
}

fn accept_loop(listener: TcpListener, backend: SocketAddr, stop: Arc<AtomicBool>, open: Open) {
    let next = AtomicU64::new(0);
    for client in listener.incoming() {
        if stop.load(Ordering::SeqCst) {
            break;
        }
        let Ok(client) = client else { continue };
        let id = next.fetch_add(1, Ordering::Relaxed);
        let open = open.clone();
        let _ = std::thread::Builder::new()
            .name("view-conn".into())
            .spawn(move || {
                let _ = serve(id, client, backend, &open);
                open.lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .remove(&id);
            });
    }
}

/// One connection: the handshake with the renaming, then bytes both ways.
fn serve(id: u64, mut client: TcpStream, backend: SocketAddr, open: &Open) -> io::Result<()> {
    client.set_read_timeout(Some(HANDSHAKE_TIMEOUT))?;
    let (head, rest) = read_head(&mut client)?;
    let (request, renamed) = rename_offer(&head);
    let mut server = TcpStream::connect(backend)?;
    open.lock()
        .unwrap_or_else(PoisonError::into_inner)
        .insert(id, [client.try_clone()?, server.try_clone()?]);
    server.write_all(request.as_bytes())?;
    server.write_all(&rest)?;
    server.set_read_timeout(Some(HANDSHAKE_TIMEOUT))?;
    let (reply, rest) = read_head(&mut server)?;
    let reply = if renamed {
        rename_accepted(&reply)
    } else {
        reply
    };
    client.write_all(reply.as_bytes())?;
    client.write_all(&rest)?;
    client.set_read_timeout(None)?;
    server.set_read_timeout(None)?;
    let (mut c_in, mut s_out) = (client.try_clone()?, server.try_clone()?);
    let upstream = std::thread::Builder::new()
        .name("view-conn-up".into())
        .spawn(move || {
            let _ = io::copy(&mut c_in, &mut s_out);
            let _ = s_out.shutdown(Shutdown::Write);
        })?;
    let _ = io::copy(&mut server, &mut client);
    let _ = client.shutdown(Shutdown::Both);
    let _ = server.shutdown(Shutdown::Both);
    let _ = upstream.join();
    Ok(())
}

/// Read an HTTP head (through the blank line) and whatever came after it in the same reads.
fn read_head(s: &mut TcpStream) -> io::Result<(String, Vec<u8>)> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 2048];
    loop {
        if let Some(end) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
            let rest = buf.split_off(end + 4);
            let head = String::from_utf8(buf)
                .map_err(|_| io::Error::new(io::ErrorKind::InvalidData, "HTTP head not UTF-8"))?;
            return Ok((head, rest));
        }
        if buf.len() > MAX_HEAD {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                "HTTP head too long",
            ));
        }
        let n = s.read(&mut chunk)?;
        if n == 0 {
            return Err(io::ErrorKind::UnexpectedEof.into());
        }
        buf.extend_from_slice(&chunk[..n]);
    }
}

fn is_protocol_header(line: &str) -> Option<(&str, &str)> {
    let (name, value) = line.split_once(':')?;
    name.trim()
        .eq_ignore_ascii_case("sec-websocket-protocol")
        .then_some((name, value))
}

/// The request with a lone classic offer renamed for the SDK, and whether it was renamed. A request that
/// already offers a name the SDK knows is left as it is.
pub fn rename_offer(head: &str) -> (String, bool) {
    let offers: Vec<&str> = head
        .split("\r\n")
        .filter_map(is_protocol_header)
        .flat_map(|(_, v)| v.split(','))
        .map(str::trim)
        .collect();
    if offers.iter().any(|o| SDK_NAMES.contains(o)) || !offers.contains(&CLASSIC) {
        return (head.to_string(), false);
    }
    let lines = head
        .split("\r\n")
        .map(|line| match is_protocol_header(line) {
            Some((name, value)) => {
                let names: Vec<&str> = value
                    .split(',')
                    .map(str::trim)
                    .map(|o| if o == CLASSIC { SDK } else { o })
                    .collect();
                format!("{name}: {}", names.join(", "))
            }
            None => line.to_string(),
        });
    (lines.collect::<Vec<_>>().join("\r\n"), true)
}

/// The SDK's reply with the accepted protocol named as the client offered it.
pub fn rename_accepted(head: &str) -> String {
    head.split("\r\n")
        .map(|line| match is_protocol_header(line) {
            Some((name, value)) if value.trim() == SDK => format!("{name}: {CLASSIC}"),
            _ => line.to_string(),
        })
        .collect::<Vec<_>>()
        .join("\r\n")
}

#[cfg(test)]
mod tests {
    use super::*;

    const REQ: &str = "GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n";

    #[test]
    fn a_lone_classic_offer_is_renamed_both_ways() {
        let head = format!("{REQ}Sec-WebSocket-Protocol: {CLASSIC}\r\n\r\n");
        let (req, renamed) = rename_offer(&head);
        assert!(renamed);
        assert!(
            req.contains(&format!("Sec-WebSocket-Protocol: {SDK}\r\n")),
            "{req}"
        );
        assert!(req.ends_with("\r\n\r\n"));
        let reply = format!(
            "HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: {SDK}\r\nconnection: Upgrade\r\n\r\n"
        );
        let back = rename_accepted(&reply);
        assert!(back.contains(&format!("sec-websocket-protocol: {CLASSIC}\r\n")));
        assert!(back.ends_with("\r\n\r\n"));
    }

    #[test]
    fn offers_the_sdk_knows_and_unknown_offers_pass_unchanged() {
        for offer in [
            format!("{SDK}, {CLASSIC}"),
            format!("{CLASSIC}, foxglove.sdk.v1.1"),
            "foxglove.sdk.v2".to_string(),
            "something.else".to_string(),
        ] {
            let head = format!("{REQ}sec-websocket-protocol: {offer}\r\n\r\n");
            assert_eq!(rename_offer(&head), (head.clone(), false));
        }
        // Several headers and other names beside the classic one: only the classic one is renamed.
        let head = format!(
            "{REQ}Sec-WebSocket-Protocol: chat\r\nSec-WebSocket-Protocol: {CLASSIC}, x\r\n\r\n"
        );
        let (req, renamed) = rename_offer(&head);
        assert!(renamed);
        assert!(req.contains("Sec-WebSocket-Protocol: chat\r\n"));
        assert!(req.contains(&format!("Sec-WebSocket-Protocol: {SDK}, x\r\n")));
        // No header at all: passed on (the SDK answers 400).
        let head = format!("{REQ}\r\n");
        assert_eq!(rename_offer(&head), (head.clone(), false));
    }
}
