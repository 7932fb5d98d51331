//! Connections that fall silent are closed: an idle timeout on every accepted socket.
//!
//! Without it a client that sends half a request's headers, or a large body's first
//! megabytes, and then nothing, holds its connection (and the body read so far) for ever:
//! hyper's own header timeout needs a timer that `axum::serve` does not give it, and nothing
//! bounds a body that stops arriving, so a few such uploads could hold hundreds of MB until
//! their clients give up.
//!
//! **What it is.** A [`Listener`] whose sockets fail a pending read with `TimedOut` once no
//! byte has moved either way for `idle`. Any byte read or written restarts the clock, so a
//! slow upload or a slow download that keeps moving is never cut. hyper keeps a read
//! pending while a handler runs (to notice a client that goes away), so a handler that
//! sends nothing for longer than `idle` is cut too: `idle` must stay above the longest wait
//! a route offers (60 s, `GET /jobs/{id}?wait=`). An idle keep-alive connection is closed
//! after `idle`, as servers do; clients open a new one.
//!
//! **What it is not.** It bounds silence, not the total time of a request, and it does not
//! limit how many connections one client opens.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Duration;

use axum::serve::Listener;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::time::{Instant, Sleep};

/// A TCP listener whose connections time out when their peer stops sending.
pub struct IdleListener {
    inner: TcpListener,
    idle: Duration,
}

impl IdleListener {
    pub fn new(inner: TcpListener, idle: Duration) -> IdleListener {
        IdleListener { inner, idle }
    }
}

impl Listener for IdleListener {
    type Io = IdleStream;
    type Addr = std::net::SocketAddr;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        // axum's own accept loop: retries (after a pause) on errors such as too many files.
        let (stream, addr) = Listener::accept(&mut self.inner).await;
        // Without TCP_NODELAY a response written in more than one piece (a PNG streamed
        // chunk by chunk, headers before a body) waits for the client's delayed ACK before
        // its last small segment (Nagle's algorithm), a delay of tens of ms on many
        // downloads. Every write here is a whole piece of a response, so nothing is
        // gained by holding it back. A socket that refuses the option still works, slower.
        if let Err(e) = stream.set_nodelay(true) {
            tracing::debug!("TCP_NODELAY on a connection from {addr}: {e}");
        }
        (IdleStream::new(stream, self.idle), addr)
    }

    fn local_addr(&self) -> io::Result<Self::Addr> {
        self.inner.local_addr()
    }
}

/// A socket whose pending reads fail after `idle` without a byte moving either way.
pub struct IdleStream {
    io: TcpStream,
    idle: Duration,
    /// Armed when a read starts waiting; disarmed when one completes; pushed back by every
    /// write that moves bytes.
    timer: Pin<Box<Sleep>>,
    armed: bool,
}

impl IdleStream {
    fn new(io: TcpStream, idle: Duration) -> IdleStream {
        IdleStream {
            io,
            idle,
            timer: Box::pin(tokio::time::sleep(idle)),
            armed: false,
        }
    }
}

impl IdleStream {
    /// Bytes written count as the connection being alive.
    fn wrote(&mut self, r: &Poll<io::Result<usize>>) {
        if self.armed && matches!(r, Poll::Ready(Ok(n)) if *n > 0) {
            self.timer.as_mut().reset(Instant::now() + self.idle);
        }
    }
}

impl AsyncRead for IdleStream {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        match Pin::new(&mut this.io).poll_read(cx, buf) {
            Poll::Ready(r) => {
                this.armed = false;
                Poll::Ready(r)
            }
            Poll::Pending => {
                if !this.armed {
                    this.timer.as_mut().reset(Instant::now() + this.idle);
                    this.armed = true;
                }
                match this.timer.as_mut().poll(cx) {
                    Poll::Ready(()) => Poll::Ready(Err(io::Error::new(
                        io::ErrorKind::TimedOut,
                        format!("nothing received for {} s", this.idle.as_secs()),
                    ))),
                    Poll::Pending => Poll::Pending,
                }
            }
        }
    }
}

impl AsyncWrite for IdleStream {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let r = Pin::new(&mut this.io).poll_write(cx, buf);
        this.wrote(&r);
        r
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let r = Pin::new(&mut this.io).poll_write_vectored(cx, bufs);
        this.wrote(&r);
        r
    }

    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().io).poll_flush(cx)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().io).poll_shutdown(cx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An accepted socket sends each write at once: with Nagle's algorithm on, the last
    /// small piece of a PNG streamed chunk by chunk would wait for the client's delayed ACK.
    #[tokio::test]
    async fn accepted_connections_send_without_delay() {
        // A loopback listener on a free port: binding cannot fail on a working host.
        let inner = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = inner.local_addr().unwrap();
        let mut listener = IdleListener::new(inner, Duration::from_secs(5));
        let (accepted, client) = tokio::join!(listener.accept(), TcpStream::connect(addr));
        let client = client.unwrap();
        // The client's side is left as the OS made it: only the service's side is ours.
        assert!(!client.nodelay().unwrap());
        assert!(accepted.0.io.nodelay().unwrap());
    }
}
