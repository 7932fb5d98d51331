//! A job as the API shows it ([`JobView`]): its row, with its progress, its URLs and, while
//! the farm cannot store pixels, why it waits. The JSON of `GET /jobs/{id}`, of every job
//! answer, and of the job's events.

use serde::Serialize;
use utoipa::ToSchema;

use crate::now_ms;
use crate::state::AppState;
use crate::store::{JobRow, STORAGE_PAUSE};

/// A job as the API shows it.
#[derive(Debug, Serialize, ToSchema)]
pub struct JobView {
    #[serde(flatten)]
    pub row: JobRow,
    /// Fraction of tiles done, 0 to 1.
    pub progress: f64,
    /// The job: its JSON for a script, its page for a browser.
    pub url: String,
    /// Its PNG, once done.
    pub image_url: String,
    /// Its image as far as it is rendered (RGBA; transparent where no tile is stored yet).
    pub preview_url: String,
    /// Its server-sent events.
    pub events_url: String,
    /// Why a job still to finish makes no progress now: the service cannot store tile
    /// pixels (a full disk), or it started without room to write, so no tile is handed out
    /// until it can again. Absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub paused: Option<String>,
}

impl From<JobRow> for JobView {
    fn from(row: JobRow) -> JobView {
        let progress = if row.tiles_total > 0 {
            row.tiles_done as f64 / row.tiles_total as f64
        } else {
            0.0
        };
        JobView {
            url: format!("/jobs/{}", row.id),
            image_url: format!("/jobs/{}/image.png", row.id),
            preview_url: format!("/jobs/{}/preview.png", row.id),
            events_url: format!("/jobs/{}/events", row.id),
            progress,
            row,
            paused: None,
        }
    }
}

impl JobView {
    /// The job as the API shows it, with the service's state: one with tiles still to
    /// render says so while the farm is paused for storage
    /// ([`Store::storage_trouble`](crate::store::Store::storage_trouble)), which otherwise
    /// only `/healthz` told. The reason is given in general terms: the failed write's own
    /// message names another job's spool file.
    pub(crate) fn of(state: &AppState, row: JobRow) -> JobView {
        let waiting = row.state.is_active() && row.tiles_done < row.tiles_total;
        let mut view = JobView::from(row);
        if waiting && state.read_only.why().is_some() {
            view.paused = Some(
                "the service started without room to write, and takes no work until the \
                 disk has room"
                    .to_string(),
            );
        } else if waiting
            && state
                .store
                .storage_trouble(now_ms(), STORAGE_PAUSE)
                .is_some()
        {
            view.paused = Some(
                "the service has no room to store tile pixels now (a full disk, or no file \
                 descriptors to spare): tiles are handed out again once it has"
                    .to_string(),
            );
        }
        view
    }
}
