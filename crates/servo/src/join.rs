//! Joining a thread with a time bound (the session's servo thread, the connector thread).

use std::thread::JoinHandle;
use std::time::Duration;

/// Waits for `thread` to finish, at most `bound` (checked every 2 ms); gives the handle back if it did not.
pub(crate) fn join_within<T>(
    thread: JoinHandle<T>,
    bound: Duration,
) -> Result<std::thread::Result<T>, JoinHandle<T>> {
    let start = std::time::Instant::now();
    while !thread.is_finished() {
        if start.elapsed() >= bound {
            return Err(thread);
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    Ok(thread.join())
}
