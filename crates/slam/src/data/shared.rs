//! The map as tracking, local mapping and loop closing share it.

use std::sync::{LockResult, Mutex, MutexGuard, PoisonError};

use super::Map;

/// The map behind a lock that is served in turn: a thread waiting for it gets it before one
/// that has just released it and asks again.
///
/// A plain `Mutex` lets the releasing thread take the lock straight back. Local mapping takes
/// the map for one short batch of work after another, and tracking, woken each time too late,
/// waited 20-40 ms for it on one frame in ten (living_turn, real time, two cores). Here each
/// thread first passes a turnstile that the waiting thread holds while it waits.
#[derive(Debug, Default)]
pub struct SharedMap {
    map: Mutex<Map>,
    turnstile: Mutex<()>,
}

impl SharedMap {
    /// Share `map`.
    pub fn new(map: Map) -> Self {
        Self {
            map: Mutex::new(map),
            turnstile: Mutex::new(()),
        }
    }

    /// The map, once the threads that asked first have had it (an error when a thread
    /// panicked while holding it).
    ///
    /// ```
    /// use stillpoint_slam::data::{Map, SharedMap};
    /// let shared = SharedMap::new(Map::new());
    /// assert!(shared.lock().unwrap().points.is_empty());
    /// ```
    pub fn lock(&self) -> LockResult<MutexGuard<'_, Map>> {
        // The turnstile guards nothing; its poison says nothing about the map.
        let _turn = self
            .turnstile
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        self.map.lock()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::sync::mpsc::channel;

    #[test]
    fn a_waiting_thread_gets_the_map_before_the_holder_takes_it_again() {
        let shared = Arc::new(SharedMap::new(Map::new()));
        let (asking, asked) = channel();
        let (got, gotten) = channel();
        let held = shared.lock().unwrap();
        let waiter = {
            let shared = Arc::clone(&shared);
            std::thread::spawn(move || {
                asking.send(()).unwrap();
                let mut m = shared.lock().unwrap();
                m.epoch = 7;
                got.send(()).unwrap();
            })
        };
        asked.recv().unwrap();
        // The waiter is at the map or about to be; give it the turnstile for certain by waiting
        // until it holds it (it holds it while it waits for the map).
        while shared.turnstile.try_lock().is_ok() {
            std::thread::yield_now();
        }
        drop(held);
        // Asking again now queues behind the waiter, so it sees the waiter's write.
        let again = shared.lock().unwrap();
        assert_eq!(again.epoch, 7);
        drop(again);
        gotten.recv().unwrap();
        waiter.join().unwrap();
    }
}
