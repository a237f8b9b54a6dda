//! The UDP plumbing both datagram devices share: a socket connected to the
//! device, and receiving one datagram before a deadline.

use std::io::ErrorKind;
use std::net::UdpSocket;
use std::time::Instant;

/// A socket on an ephemeral local port, connected to `host:port` (so datagrams
/// from anyone else are dropped by the kernel).
pub fn connect(host: &str, port: u16) -> std::io::Result<UdpSocket> {
    let socket = UdpSocket::bind(("0.0.0.0", 0))?;
    socket.connect((host, port))?;
    Ok(socket)
}

/// One datagram into `buffer` before `deadline`: its length, or `None` when the
/// deadline passed first.
pub fn recv_before(
    socket: &UdpSocket,
    buffer: &mut [u8],
    deadline: Instant,
) -> std::io::Result<Option<usize>> {
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Ok(None);
        }
        socket.set_read_timeout(Some(left))?;
        match socket.recv(buffer) {
            Ok(n) => return Ok(Some(n)),
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            Err(e) => return Err(e),
        }
    }
}
