//! The ids of jobs this process changes, told to whoever follows them (the job's event
//! streams): a wake-up, not a record. What changed is read from the database by the
//! follower; this only says when to look.

use std::sync::Arc;

use tokio::sync::broadcast;

/// The ids of jobs this process just changed, for the streams that follow them. A lagging
/// receiver loses ids, never a change: it reads its job again at once.
#[derive(Debug, Clone)]
pub struct Changes(broadcast::Sender<Arc<str>>);

impl Default for Changes {
    fn default() -> Self {
        Changes(broadcast::channel(1024).0)
    }
}

/// The id a change of many jobs at once is told with (a maintenance pass).
pub const ANY_JOB: &str = "";

impl Changes {
    /// Tells the streams of job `id` that it changed.
    pub fn job(&self, id: &str) {
        // No receiver: no stream is open, nobody to tell.
        let _ = self.0.send(Arc::from(id));
    }

    /// Tells every stream that its job may have changed.
    pub fn any(&self) {
        let _ = self.0.send(Arc::from(ANY_JOB));
    }

    /// A receiver of the ids told from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<Arc<str>> {
        self.0.subscribe()
    }
}
