//! A minimal HTTP/1.1 server for the few documents flowopt serves on a
//! lab's network (the metrics, the live view's page): `GET` of a path,
//! answered from a routing function, one connection at a time, from a
//! thread of its own for as long as the process lives.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::time::Duration;

use tracing::warn;

/// A document: its content type and body.
pub type Document = (&'static str, String);

/// Serves `route(path)` for every `GET path` on `addr` (404 where it
/// answers `None`, with `missing` as the body) from a thread named
/// `name`. Returns the address bound (`addr` with port 0 gets one from
/// the system).
pub fn serve(
    addr: SocketAddr,
    name: &str,
    missing: &'static str,
    route: impl Fn(&str) -> Option<Document> + Send + 'static,
) -> std::io::Result<SocketAddr> {
    let listener = TcpListener::bind(addr)?;
    let bound = listener.local_addr()?;
    let thread = name.to_string();
    std::thread::Builder::new().name(thread.clone()).spawn(move || {
        for stream in listener.incoming().flatten() {
            if let Err(e) = respond(stream, missing, &route) {
                warn!("{thread}: request failed: {e}");
            }
        }
    })?;
    Ok(bound)
}

/// Answers one request.
fn respond(mut stream: TcpStream, missing: &str, route: &impl Fn(&str) -> Option<Document>) -> std::io::Result<()> {
    stream.set_read_timeout(Some(Duration::from_secs(2)))?;
    // The request head, up to its blank line (closing with unread bytes
    // would reset the connection before the client reads the answer).
    let mut request = Vec::with_capacity(1024);
    let mut chunk = [0u8; 1024];
    while !request.windows(4).any(|w| w == b"\r\n\r\n") && request.len() < 16 * 1024 {
        let n = stream.read(&mut chunk)?;
        if n == 0 {
            break;
        }
        request.extend_from_slice(&chunk[..n]);
    }
    let line = String::from_utf8_lossy(&request);
    let path = line.split_whitespace().nth(1).unwrap_or("");
    let path = path.split('?').next().unwrap_or("");
    let found = if line.starts_with("GET ") { route(path) } else { None };
    let (status, (kind, body)) = match found {
        Some(document) => ("200 OK", document),
        None => ("404 Not Found", ("text/plain; charset=utf-8", missing.to_string())),
    };
    let head = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
        body.len()
    );
    stream.write_all(head.as_bytes())?;
    stream.write_all(body.as_bytes())
}

/// `GET path` from `addr`: the whole response, head and body (for tests).
pub fn get(addr: SocketAddr, path: &str) -> std::io::Result<String> {
    let mut stream = TcpStream::connect(addr)?;
    stream.write_all(format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\n\r\n").as_bytes())?;
    let mut text = String::new();
    stream.read_to_string(&mut text)?;
    Ok(text)
}
