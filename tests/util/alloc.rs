//! A counting global allocator: counts allocations, reallocations and frees made by the current thread while
//! counting is switched on for it. Other test threads running in parallel are not counted.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

pub struct CountingAllocator;

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static EVENTS: Cell<u64> = const { Cell::new(0) };
}

fn note() {
    // try_with: the thread-local may already be gone while a thread shuts down.
    let _ = COUNTING.try_with(|counting| {
        if counting.get() {
            let _ = EVENTS.try_with(|events| events.set(events.get() + 1));
        }
    });
}

unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note();
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note();
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        note();
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Runs `f` and returns its result with the number of allocation events (alloc, realloc, free) it made on this
/// thread.
pub fn count_allocations<T>(f: impl FnOnce() -> T) -> (T, u64) {
    EVENTS.with(|events| events.set(0));
    COUNTING.with(|counting| counting.set(true));
    let result = f();
    COUNTING.with(|counting| counting.set(false));
    (result, EVENTS.with(|events| events.get()))
}

#[test]
fn the_counter_sees_allocations() {
    let ((), events) = count_allocations(|| drop(std::hint::black_box(vec![1u8; 64])));
    assert_eq!(events, 2, "one allocation and one free");
    let (_, events) = count_allocations(|| std::hint::black_box(3 + 4));
    assert_eq!(events, 0);
}
