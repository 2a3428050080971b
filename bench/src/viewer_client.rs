//! A Foxglove viewer for `tes bench latency --foxglove`: a WebSocket client of the launcher's
//! live server that subscribes to every channel it advertises and reads every message, as the
//! Foxglove app does, so the blocks with the server measure it serving.
//!
//! It runs on a thread of its own, placed as the launcher's server threads are (off the acting
//! CPU, lowest priority): a viewer on the robot's host, not a second load on the acting core.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

use crate::error::{BenchError, Result};

/// The Foxglove SDK's WebSocket subprotocol (channel advertisements with their schemas).
const SUBPROTOCOL: &str = "foxglove.sdk.v1";

/// A running viewer; [`stop`](Self::stop) ends it.
#[derive(Debug)]
pub struct ViewerClient {
    stop: Arc<AtomicBool>,
    received: Arc<AtomicU64>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl ViewerClient {
    /// Connects to the server at `addr` (retrying for a few seconds while it starts).
    pub fn connect(addr: SocketAddr) -> Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let received = Arc::new(AtomicU64::new(0));
        let (flag, count) = (stop.clone(), received.clone());
        let thread = std::thread::Builder::new()
            .name("bench-viewer".into())
            .spawn(move || {
                tes_runtime::affinity::make_this_a_background_thread("the bench's viewer");
                let runtime = tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build();
                match runtime {
                    Ok(rt) => {
                        if let Err(e) = rt.block_on(follow(addr, &flag, &count)) {
                            tracing::warn!("the bench's Foxglove viewer stopped: {e}");
                        }
                    }
                    Err(e) => tracing::warn!("the bench's Foxglove viewer cannot start: {e}"),
                }
            })
            .map_err(BenchError::io(
                "cannot start the bench's Foxglove viewer".into(),
            ))?;
        Ok(Self {
            stop,
            received,
            thread: Some(thread),
        })
    }

    /// Ends the viewer; returns the messages it received.
    pub fn stop(mut self) -> u64 {
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.received.load(Ordering::Acquire)
    }
}

impl Drop for ViewerClient {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Connects, subscribes to each advertised channel and counts the messages until stopped (or
/// the server goes away).
async fn follow(
    addr: SocketAddr,
    stop: &AtomicBool,
    received: &AtomicU64,
) -> std::result::Result<(), Box<dyn std::error::Error>> {
    let mut request = format!("ws://{addr}").into_client_request()?;
    request
        .headers_mut()
        .insert("Sec-WebSocket-Protocol", SUBPROTOCOL.parse()?);
    let mut tries = 0;
    let (mut socket, _) = loop {
        match tokio_tungstenite::connect_async(request.clone()).await {
            Ok(connected) => break connected,
            Err(_) if tries < 50 && !stop.load(Ordering::Acquire) => {
                tries += 1;
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
            Err(e) => return Err(e.into()),
        }
    };
    let mut next_id = 1u64;
    while !stop.load(Ordering::Acquire) {
        let message = match tokio::time::timeout(Duration::from_millis(50), socket.next()).await {
            Err(_) => continue,
            Ok(None) => return Ok(()),
            Ok(Some(m)) => m?,
        };
        match message {
            Message::Binary(_) => {
                received.fetch_add(1, Ordering::Relaxed);
            }
            Message::Text(text) => {
                let said: serde_json::Value = serde_json::from_str(text.as_str())?;
                if said["op"] == "advertise" {
                    let channels = said["channels"].as_array().cloned().unwrap_or_default();
                    let subscriptions: Vec<serde_json::Value> = channels
                        .iter()
                        .map(|c| {
                            next_id += 1;
                            serde_json::json!({"id": next_id, "channelId": c["id"]})
                        })
                        .collect();
                    let subscribe =
                        serde_json::json!({"op": "subscribe", "subscriptions": subscriptions});
                    socket.send(Message::text(subscribe.to_string())).await?;
                }
            }
            _ => {}
        }
    }
    let _ = socket.close(None).await;
    Ok(())
}
