//! Giving freed memory back to the operating system.
//!
//! The C allocator keeps what a process frees for its own reuse, in every thread's arena:
//! after a burst of large allocations (checking large scenes on the blocking threads) the
//! process stays that large for good. [`give_back`] returns the free pages. Not an
//! allocator of its own, and a no-op where the C library offers no such call.

/// Returns the allocator's free memory to the operating system, as far as it can.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
pub fn give_back() {
    // SAFETY: `malloc_trim` takes a byte count to keep at the top of the heap and touches
    // only the allocator's own free lists, under its own locks; any thread may call it.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Returns the allocator's free memory to the operating system: nothing to do with this C
/// library.
#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn give_back() {}
