//! A counting global allocator: counts allocations, reallocations and frees made by the current thread while
//! counting is switched on for it. Other test threads running in parallel are not counted.
//!
//! The first counted event of each [`count_allocations`] is also captured with its backtrace and printed to the
//! test's stderr (shown when the test fails), so a rare allocation on the servo path, seen once in a CI run,
//! names its source in that run's log instead of only its count.

use std::alloc::{GlobalAlloc, Layout, System};
use std::backtrace::Backtrace;
use std::cell::{Cell, RefCell};

pub struct CountingAllocator;

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
    static EVENTS: Cell<u64> = const { Cell::new(0) };
    static FIRST: RefCell<Option<(&'static str, usize, Backtrace)>> = const { RefCell::new(None) };
}

fn note(what: &'static str, bytes: usize) {
    // try_with: the thread-local may already be gone while a thread shuts down.
    let _ = COUNTING.try_with(|counting| {
        if counting.get() {
            let first = EVENTS
                .try_with(|events| {
                    events.set(events.get() + 1);
                    events.get() == 1
                })
                .unwrap_or(false);
            if first {
                // Capturing allocates: stop counting meanwhile, so those allocations neither count nor recurse.
                counting.set(false);
                let backtrace = Backtrace::force_capture();
                let _ = FIRST.try_with(|slot| *slot.borrow_mut() = Some((what, bytes, backtrace)));
                counting.set(true);
            }
        }
    });
}

unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note("alloc", layout.size());
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note("alloc_zeroed", layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        note("dealloc", layout.size());
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note("realloc", new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Runs `f` and returns its result with the number of allocation events (alloc, realloc, free) it made on this
/// thread. When there were any, the first one's backtrace goes to stderr.
pub fn count_allocations<T>(f: impl FnOnce() -> T) -> (T, u64) {
    FIRST.with(|slot| slot.borrow_mut().take());
    EVENTS.with(|events| events.set(0));
    COUNTING.with(|counting| counting.set(true));
    let result = f();
    COUNTING.with(|counting| counting.set(false));
    let events = EVENTS.with(|events| events.get());
    if let Some((what, bytes, backtrace)) = FIRST.with(|slot| slot.borrow_mut().take()) {
        eprintln!("count_allocations: {events} events; the first, {what} of {bytes} bytes, at:\n{backtrace}");
    }
    (result, events)
}

#[test]
fn the_counter_sees_allocations() {
    let ((), events) = count_allocations(|| drop(std::hint::black_box(vec![1u8; 64])));
    assert_eq!(events, 2, "one allocation and one free");
    let (_, events) = count_allocations(|| std::hint::black_box(3 + 4));
    assert_eq!(events, 0);
}

#[test]
fn the_first_counted_event_is_captured_with_its_backtrace() {
    EVENTS.with(|events| events.set(0));
    COUNTING.with(|counting| counting.set(true));
    drop(std::hint::black_box(vec![7u8; 48]));
    COUNTING.with(|counting| counting.set(false));
    let first = FIRST.with(|slot| slot.borrow_mut().take());
    let (what, bytes, backtrace) = first.expect("the first event was captured");
    assert_eq!((what, bytes), ("alloc", 48));
    assert_eq!(
        EVENTS.with(|events| events.get()),
        2,
        "capturing the backtrace was not counted"
    );
    let text = backtrace.to_string();
    assert!(
        text.contains("the_first_counted_event_is_captured_with_its_backtrace"),
        "the backtrace names this test: {text}"
    );
}
