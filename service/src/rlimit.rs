//! The open-file limit: raised at start from the soft limit to the hard one.
//!
//! Every connection is a file descriptor. At a typical soft limit of 1,024, a few hundred
//! idle or slow clients (each held until `--idle-timeout-secs`) would use up the rest, and
//! every new connection, `/healthz` and the local workers' own included, would wait in the
//! kernel's queue. The hard limit, which a process may raise itself to, is usually far
//! higher. Nothing here can fail the start: a limit that cannot be read or raised is left
//! as it is.

/// The soft limit raised to the hard one; returns `(before, after)` when it changed.
#[cfg(unix)]
pub fn raise_open_files() -> Option<(u64, u64)> {
    use rustix::process::{Resource, getrlimit, setrlimit};
    let limit = getrlimit(Resource::Nofile);
    let (current, maximum) = (limit.current?, limit.maximum);
    // At most 2^20, the kernel's usual ceiling for this resource (`fs.nr_open`), also when
    // the hard limit says "unlimited"; a raise the kernel refuses changes nothing.
    // A kernel may refuse less than the hard limit (macOS: above `kern.maxfilesperproc`,
    // with an unlimited hard limit): halved until one is taken.
    let mut target = maximum.map_or(1 << 20, |m| m.min(1 << 20));
    while target > current {
        let raised = rustix::process::Rlimit {
            current: Some(target),
            maximum,
        };
        if setrlimit(Resource::Nofile, raised).is_ok() {
            return Some((current, target));
        }
        target /= 2;
    }
    None
}

#[cfg(not(unix))]
pub fn raise_open_files() -> Option<(u64, u64)> {
    None
}
