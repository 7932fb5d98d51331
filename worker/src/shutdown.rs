//! The graceful stop: when it begins, the pauses it cuts short, and the end of its grace
//! period, after which what a worker still holds is given up.
//!
//! Not the signals that ask for it (`cli.rs`), nor what each slot gives back (`slot.rs`
//! and `lease.rs`).

use std::future::Future;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::sync::watch;
use tracing::info;

use crate::shared::Shared;

/// Spawns the task that turns `shutdown`'s completion into the stop: the moment is noted
/// (the grace period counts from it) and `stop` says `true` to every slot.
pub(crate) fn on_shutdown(
    shared: Arc<Shared>,
    shutdown: impl Future<Output = ()> + Send + 'static,
    stop: watch::Sender<bool>,
) {
    tokio::spawn(async move {
        shutdown.await;
        shared.stopping_since.get_or_init(Instant::now);
        info!(
            grace_secs = shared.cfg.grace.as_secs(),
            "stopping: finishing the tiles being rendered, giving back the rest"
        );
        let _ = stop.send(true);
    });
}

/// Waits `d`, or less if a shutdown is requested. Returns whether shutdown is requested.
pub(crate) async fn pause(d: Duration, stop: &mut watch::Receiver<bool>) -> bool {
    if *stop.borrow() {
        return true;
    }
    tokio::select! {
        _ = tokio::time::sleep(d) => *stop.borrow(),
        _ = stop.changed() => true,
    }
}

/// Completes once the worker is stopping and its grace period is over.
pub(crate) async fn grace_over(shared: &Shared, mut stop: watch::Receiver<bool>) {
    if stop.wait_for(|s| *s).await.is_err() {
        // The sender is gone: the stop cannot come any more.
        std::future::pending::<()>().await;
    }
    let since = *shared.stopping_since.get_or_init(Instant::now);
    tokio::time::sleep_until((since + shared.cfg.grace).into()).await;
}
