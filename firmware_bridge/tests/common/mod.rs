//! Helpers shared by the bridge's integration tests.

use std::net::UdpSocket;

/// A loopback UDP port that was free a moment ago (the OS picked it).
pub fn free_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}
