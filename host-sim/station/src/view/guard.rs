//! What a viewer client may ask of the server, and what the server refuses.
//!
//! Foxglove's SDK parses every client message itself: a message that is not the protocol, a frame larger
//! than its limit (16 MiB; the header is checked before the payload is read) or a subscription to a
//! channel that does not exist is answered with an error status or a closed connection, and reported
//! only through `tracing` at level ERROR. [`RefusalCounter`] is a `tracing` subscriber that counts those
//! reports, so the base station can say how many it refused ([`refused`]). It keeps nothing else: the
//! SDK's other messages are dropped.
//!
//! The query phrase is the one parameter a client may set ([`QUERY_PARAMETER`]); [`QueryParameter`]
//! hands it to the view thread and never blocks the client's poll loop.

use foxglove::websocket::{
    AnyClient, ChannelView, Client, GetParametersResponder, Parameter, ParameterHandler,
    ParameterValue, ServerListener, SetParametersResponder,
};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Once};
use tracing::field::{Field, Visit};
use tracing::span::{Attributes, Id, Record};
use tracing::{Event, Level, Metadata, Subscriber};

/// The parameter that holds the query phrase.
pub const QUERY_PARAMETER: &str = "query";

static REFUSED: AtomicU64 = AtomicU64::new(0);
static INSTALL: Once = Once::new();

/// The SDK's reports of a client message it refused (a part of their text).
const REFUSALS: [&str; 5] = [
    "Invalid message",
    "Error receiving from client",
    "Dropping client",
    "attempted to subscribe to unknown channel",
    "Received message for unknown channel",
];

/// Client messages refused since the process started (garbage, oversized, unknown channels).
pub fn refused() -> u64 {
    REFUSED.load(Ordering::Relaxed)
}

/// Install the [`RefusalCounter`] as the process's `tracing` subscriber (once; if another subscriber was
/// installed first, refusals are not counted and this returns false).
pub fn install_refusal_counter() -> bool {
    let mut ok = true;
    INSTALL.call_once(|| ok = tracing::subscriber::set_global_default(RefusalCounter).is_ok());
    ok
}

/// Counts the SDK's ERROR reports of refused client messages.
pub struct RefusalCounter;

struct MessageText(String);

impl Visit for MessageText {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
}

impl Subscriber for RefusalCounter {
    fn enabled(&self, m: &Metadata<'_>) -> bool {
        *m.level() == Level::ERROR && m.target().starts_with("foxglove::websocket")
    }
    fn new_span(&self, _: &Attributes<'_>) -> Id {
        Id::from_u64(1)
    }
    fn record(&self, _: &Id, _: &Record<'_>) {}
    fn record_follows_from(&self, _: &Id, _: &Id) {}
    fn event(&self, event: &Event<'_>) {
        let mut text = MessageText(String::new());
        event.record(&mut text);
        if REFUSALS.iter().any(|r| text.0.contains(r)) {
            REFUSED.fetch_add(1, Ordering::Relaxed);
        }
    }
    fn enter(&self, _: &Id) {}
    fn exit(&self, _: &Id) {}
}

/// What the server tells the view thread.
pub trait ViewRequests: Send + Sync + 'static {
    /// A client subscribed to `topic`: send it the whole layer.
    fn full_scene(&self, sink: foxglove::SinkId, topic: &str);
    /// A client set the query phrase (empty: no query).
    fn set_phrase(&self, phrase: String);
    /// The phrase now in force.
    fn phrase(&self) -> String;
}

/// Late joiners: each new subscription asks the view thread for the whole layer.
pub struct Subscriptions(pub Arc<dyn ViewRequests>);

impl ServerListener for Subscriptions {
    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        if let Some(sink) = client.sink_id() {
            self.0.full_scene(sink, channel.topic());
        }
    }
}

/// The query phrase as a Foxglove parameter.
pub struct QueryParameter(pub Arc<dyn ViewRequests>);

impl QueryParameter {
    fn current(&self) -> Parameter {
        Parameter::string(QUERY_PARAMETER, self.0.phrase())
    }
}

impl ParameterHandler for QueryParameter {
    fn get(
        &self,
        _client: AnyClient,
        _names: Vec<String>,
        _request_id: Option<String>,
        responder: GetParametersResponder,
    ) {
        responder.respond(vec![self.current()]);
    }

    fn set(
        &self,
        _client: AnyClient,
        parameters: Vec<Parameter>,
        _request_id: Option<String>,
        responder: SetParametersResponder,
    ) {
        for p in parameters {
            if p.name == QUERY_PARAMETER {
                if let Some(ParameterValue::String(s)) = p.value {
                    self.0.set_phrase(s.trim().to_string());
                }
            }
        }
        responder.respond(vec![self.current()]);
    }
}
