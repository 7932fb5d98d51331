//! The HTTP handlers, one file per group of routes. Each handler is thin: it checks what
//! was sent, calls the queue through [`AppState`](crate::state::AppState), and maps the
//! answer to a response; errors become responses in `error`.

pub mod image;
pub mod jobs;
pub mod page;
pub mod workers;
