// A fixed arena for the TLS engine: a linked-list heap over a static array
// that counts the bytes in use, keeps the peak, and refuses (returns null)
// any allocation past a limit, which can be set below the array's size to
// play a smaller arena. What the caller does with a null is the engine's
// business: Rust's `alloc` (rustls) ends in handle_alloc_error, C (mbedtls)
// gets NULL from calloc.

use core::alloc::{GlobalAlloc, Layout};
use core::cell::UnsafeCell;
use core::sync::atomic::{AtomicUsize, Ordering};

pub struct Arena<const N: usize> {
    heap: embedded_alloc::LlffHeap,
    mem: UnsafeCell<[u8; N]>,
    init: core::sync::atomic::AtomicBool,
    pub used: AtomicUsize,
    pub peak: AtomicUsize,
    pub limit: AtomicUsize,
    pub allocs: AtomicUsize,
    pub refused: AtomicUsize,
}

unsafe impl<const N: usize> Sync for Arena<N> {}

impl<const N: usize> Arena<N> {
    pub const fn new() -> Self {
        Self {
            heap: embedded_alloc::LlffHeap::empty(),
            mem: UnsafeCell::new([0; N]),
            init: core::sync::atomic::AtomicBool::new(false),
            used: AtomicUsize::new(0),
            peak: AtomicUsize::new(0),
            // 0: the whole array (so that the arena is all zeros: .bss, not .data)
            limit: AtomicUsize::new(0),
            allocs: AtomicUsize::new(0),
            refused: AtomicUsize::new(0),
        }
    }

    pub fn contains(&self, ptr: *mut u8) -> bool {
        let start = self.mem.get() as usize;
        (start..start + N).contains(&(ptr as usize))
    }

    /// Forget the peak (the bytes in use stay) and set the limit.
    pub fn reset_peak(&self, limit: usize) {
        self.peak.store(self.used.load(Ordering::Relaxed), Ordering::Relaxed);
        self.limit.store(limit, Ordering::Relaxed);
        self.allocs.store(0, Ordering::Relaxed);
        self.refused.store(0, Ordering::Relaxed);
    }

    fn ensure_init(&self) {
        critical_section::with(|_| {
            if !self.init.load(Ordering::Relaxed) {
                // SAFETY: once, before any allocation; the array is the heap's alone.
                unsafe { self.heap.init(self.mem.get() as usize, N) };
                self.init.store(true, Ordering::Relaxed);
            }
        });
    }

    pub unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        self.ensure_init();
        // What the caller asked for: the heap's own headers are not counted
        // (the linked-list heap has none: it rounds sizes up to 8 bytes).
        let size = layout.size().next_multiple_of(8);
        let used = self.used.load(Ordering::Relaxed);
        let limit = match self.limit.load(Ordering::Relaxed) {
            0 => N,
            l => l,
        };
        if used + size > limit {
            self.refused.fetch_add(1, Ordering::Relaxed);
            return core::ptr::null_mut();
        }
        // SAFETY: forwarded.
        let ptr = unsafe { self.heap.alloc(layout) };
        if ptr.is_null() {
            self.refused.fetch_add(1, Ordering::Relaxed);
            return ptr;
        }
        let now = self.used.fetch_add(size, Ordering::Relaxed) + size;
        self.peak.fetch_max(now, Ordering::Relaxed);
        self.allocs.fetch_add(1, Ordering::Relaxed);
        ptr
    }

    pub unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        self.used.fetch_sub(layout.size().next_multiple_of(8), Ordering::Relaxed);
        // SAFETY: forwarded.
        unsafe { self.heap.dealloc(ptr, layout) }
    }
}
