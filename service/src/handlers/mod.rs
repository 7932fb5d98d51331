//! The HTTP handlers, one file per group of routes. Each handler is thin: it checks what
//! was sent, calls the queue through [`AppState`](crate::state::AppState), and maps the
//! answer to a response; errors become responses in `error`.
//!
//! The user routes carry their OpenAPI description beside them (`#[utoipa::path]`), and
//! `routes` registers them from it, so that the document served at `/openapi.json` is the
//! router's own list.

pub mod image;
pub mod jobs;
pub mod live;
pub mod page;
pub mod workers;
