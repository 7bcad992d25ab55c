//! Accepting connections: HTTP/1.1 over TCP with a deadline for request headers and a cap on
//! the connections one client address holds at once.
//!
//! `axum::serve` sets no timer on hyper, so a client that opens a connection and sends half a
//! request line held it (and a slot of the router's concurrency limit) until the request
//! timeout. Here every connection is served by hyper's HTTP/1 builder with
//! `header_read_timeout`, and a client address past [`ConnectionLimits::max_per_client`] open
//! connections gets `429` and a closed socket before anything is parsed. Request bodies have
//! their own deadlines (`body_limits` in [`super`]); WebSocket sessions, once upgraded, are
//! bounded by the session limit and their idle time (`stream`).

use std::collections::HashMap;
use std::future::Future;
use std::net::IpAddr;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::extract::ConnectInfo;
use hyper::body::Incoming;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::io::AsyncWriteExt as _;
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;
use tower::ServiceExt as _;

/// Limits on connections, before any request is routed.
#[derive(Clone, Copy, Debug)]
pub struct ConnectionLimits {
    /// Longest time from a connection's start, or the end of its previous response, to the end
    /// of a request's headers; a slower client is disconnected.
    pub header_timeout: Duration,
    /// Most connections one client address may hold open at once (WebSocket sessions count
    /// until they are upgraded; the session limit bounds them after that).
    pub max_per_client: usize,
}

/// Open connections per client address.
#[derive(Clone, Default)]
struct Clients(Arc<Mutex<HashMap<IpAddr, usize>>>);

/// One open connection of a client: gives its slot back when dropped.
struct ClientSlot {
    clients: Clients,
    ip: IpAddr,
}

impl Clients {
    fn take(&self, ip: IpAddr, max: usize) -> Option<ClientSlot> {
        let mut map = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        let open = map.entry(ip).or_insert(0);
        if *open >= max {
            return None;
        }
        *open += 1;
        Some(ClientSlot {
            clients: self.clone(),
            ip,
        })
    }
}

impl Drop for ClientSlot {
    fn drop(&mut self) {
        let mut map = self
            .clients
            .0
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if let Some(open) = map.get_mut(&self.ip) {
            *open = open.saturating_sub(1);
            if *open == 0 {
                map.remove(&self.ip);
            }
        }
    }
}

/// Serves `router` on `listener` until `shutdown` resolves, then asks every connection to
/// finish its request in flight and close, and resolves when all have closed. Each request
/// carries the peer address as [`ConnectInfo<SocketAddr>`].
pub async fn serve(
    listener: TcpListener,
    router: Router,
    limits: ConnectionLimits,
    shutdown: impl Future<Output = ()> + Send + 'static,
) {
    let clients = Clients::default();
    // Every connection task holds a receiver: the sender's `closed()` resolves when all ended.
    let (stop_tx, stop_rx) = watch::channel(false);
    let mut shutdown = std::pin::pin!(shutdown);
    loop {
        let (stream, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(pair) => pair,
                Err(err) => {
                    // Out of file descriptors and the like: back off instead of spinning.
                    tracing::warn!(%err, "accepting a connection failed");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
            () = &mut shutdown => break,
        };
        let Some(slot) = clients.take(peer.ip(), limits.max_per_client) else {
            tokio::spawn(refuse(stream, limits.max_per_client));
            continue;
        };
        let _ = stream.set_nodelay(true);
        let router = router.clone();
        let mut stop = stop_rx.clone();
        tokio::spawn(async move {
            let service = router.map_request(move |mut request: axum::http::Request<Incoming>| {
                request.extensions_mut().insert(ConnectInfo(peer));
                request.map(Body::new)
            });
            let connection = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(limits.header_timeout)
                .serve_connection(TokioIo::new(stream), TowerToHyperService::new(service))
                .with_upgrades();
            let mut connection = std::pin::pin!(connection);
            let result = tokio::select! {
                result = connection.as_mut() => result,
                changed = stop.changed() => {
                    if changed.is_ok() {
                        connection.as_mut().graceful_shutdown();
                    }
                    // Either way nothing more will change: wait for the connection alone.
                    connection.as_mut().await
                }
            };
            if let Err(err) = result {
                tracing::debug!(%err, %peer, "connection ended with an error");
            }
            drop(slot);
        });
    }
    drop(listener);
    drop(stop_rx);
    let _ = stop_tx.send(true);
    stop_tx.closed().await;
}

/// Answers a client over its connection cap with `429` and closes, within a second.
async fn refuse(mut stream: TcpStream, max: usize) {
    let body = format!(
        "{{\"error\":{{\"kind\":\"too_many_connections\",\"message\":\"too many connections \
         from this address (at most {max} at once); close some and retry\"}}}}"
    );
    let response = format!(
        "HTTP/1.1 429 Too Many Requests\r\ncontent-type: application/json\r\ncontent-length: \
         {}\r\nretry-after: 1\r\nconnection: close\r\n\r\n{body}",
        body.len()
    );
    let write = async {
        stream.write_all(response.as_bytes()).await?;
        stream.shutdown().await
    };
    let _ = tokio::time::timeout(Duration::from_secs(1), write).await;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn client_slots_are_counted_per_address_and_given_back() {
        let clients = Clients::default();
        let a: IpAddr = [127, 0, 0, 1].into();
        let b: IpAddr = [127, 0, 0, 2].into();
        let first = clients.take(a, 2).expect("first");
        let second = clients.take(a, 2).expect("second");
        assert!(clients.take(a, 2).is_none());
        assert!(clients.take(b, 2).is_some());
        drop(first);
        let third = clients.take(a, 2).expect("a slot came back");
        drop((second, third));
        assert!(clients.0.lock().expect("lock").is_empty());
    }
}
