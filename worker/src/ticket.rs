//! A claimed tile put in the render threads' line ([`Ticket`]), and how it gets there.
//!
//! Not the lease: renewing and giving back the tile are `lease.rs`'s, and what the slot
//! waits for while the tile renders is `slot.rs`'s.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use tessera_tracer::Sampler;
use tokio::sync::oneshot;

use crate::cache::Prepared;
use crate::meter::{Cost, Meter};
use crate::pool::{RenderPool, Rendered, TileWork};
use crate::servers::Claimed;

/// A claimed tile in a render thread's queue.
pub(crate) struct Ticket {
    pub(crate) claim: Claimed,
    pub(crate) rendered: oneshot::Receiver<Rendered>,
    /// Set to give the tile up: the render threads skip it, or stop mid-strip.
    pub(crate) cancel: Arc<AtomicBool>,
    /// Set when a render thread begins the tile: what the lease renewals say (`rendering`),
    /// since with threads shared by the slots the tile held ahead may be rendering on
    /// another slot's thread while the slot's current one still waits in line.
    pub(crate) started: Arc<AtomicBool>,
    /// The rays and render-thread time the tile took, said with its result.
    pub(crate) cost: Arc<Cost>,
}

impl RenderPool {
    /// Puts a claimed tile in line, its rays counted on `meter`; a no-op worker's black
    /// tile (`scene` is `None`) is answered at once, without a trip through a thread.
    pub(crate) fn submit(
        &self,
        claim: Claimed,
        scene: Option<Arc<Prepared>>,
        meter: &Arc<Meter>,
    ) -> Ticket {
        let (reply, rendered) = oneshot::channel();
        let cancel = Arc::new(AtomicBool::new(false));
        let started = Arc::new(AtomicBool::new(false));
        let cost = Arc::new(Cost::default());
        let Some(scene) = scene else {
            let _ = reply.send(Ok(vec![0u8; claim.rect().pixel_count() * 3]));
            return Ticket {
                claim,
                rendered,
                cancel,
                started,
                cost,
            };
        };
        let (counted, meter) = (cost.clone(), meter.clone());
        let stop = cancel.clone();
        // The adaptive sampler's strips would trace their borders' rows again.
        let shareable = !matches!(scene.sampler, Sampler::Adaptive { .. });
        self.render(TileWork {
            rect: claim.rect(),
            shareable,
            // The same bytes `tessera-render` writes: a pixel's value does not depend on
            // the rectangle it is rendered in. Given up mid-strip once the slot sets
            // `cancel` (the lease is lost).
            render: Box::new(move |strip| {
                let began = Instant::now();
                let (rgb, rays) =
                    scene
                        .scene
                        .render_rect_stats_until(strip, &scene.sampler, &stop)?;
                counted.add(rays.total(), began.elapsed());
                meter.add(rays.total());
                Some(rgb)
            }),
            stop: cancel.clone(),
            started: started.clone(),
            reply,
        });
        Ticket {
            claim,
            rendered,
            cancel,
            started,
            cost,
        }
    }
}
