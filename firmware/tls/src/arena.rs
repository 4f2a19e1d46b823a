//! Mbed TLS's `calloc` and `free` over one fixed arena: the only memory
//! in the firmware handed out at run time, TLS's alone, its size the
//! board's named constant. When it is full, `calloc` returns null and Mbed
//! TLS fails what it was doing (`MBEDTLS_ERR_SSL_ALLOC_FAILED`, a refused
//! handshake); nothing panics and nothing resets.
//!
//! The arena may be made of up to [`MAX_REGIONS`] separate regions (the
//! NUCLEO's CCM RAM and a part of its SRAM): a block is taken from the
//! first region with room for it, first fit, and given back to the region
//! that holds it. A block never spans two regions.

use core::alloc::Layout;
use core::cell::RefCell;
use core::ffi::c_void;
use core::ptr::{self, NonNull};

use critical_section::Mutex;
use linked_list_allocator::Heap;

/// Every block starts with its size, so `free` can give back what `calloc`
/// took; this keeps the payload aligned for any C type.
const HEADER: usize = 16;

/// The most regions an arena is made of.
pub const MAX_REGIONS: usize = 2;

/// The arena and what it has handed out.
struct Arena {
    /// Its regions, each with its start address and length (unused: empty).
    regions: [(Heap, usize, usize); MAX_REGIONS],
    /// Bytes handed out now, and at most since [`init`] or [`reset_peak`].
    used: usize,
    peak: usize,
    /// Requests refused because the arena was full.
    refused: u32,
}

static ARENA: Mutex<RefCell<Option<Arena>>> = Mutex::new(RefCell::new(None));

/// How the arena stands.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Usage {
    /// Its size.
    pub size: usize,
    /// Bytes handed out now, headers included.
    pub used: usize,
    /// The most handed out at once.
    pub peak: usize,
    /// Requests refused for want of room.
    pub refused: u32,
}

/// Hands `memory`'s regions to Mbed TLS as its arena. Called once, by
/// [`crate::init`]; `false` (and no arena) when there are more than
/// [`MAX_REGIONS`] of them.
pub(crate) fn init(memory: impl IntoIterator<Item = &'static mut [u8]>) -> bool {
    let mut regions = [const { (Heap::empty(), 0, 0) }; MAX_REGIONS];
    let mut slots = regions.iter_mut();
    for region in memory {
        let Some((heap, start, len)) = slots.next() else { return false };
        (*start, *len) = (region.as_mut_ptr() as usize, region.len());
        // SAFETY: `region` is 'static and exclusively ours from here on:
        // the heap is its only user.
        unsafe { heap.init(region.as_mut_ptr(), region.len()) };
    }
    critical_section::with(|cs| {
        *ARENA.borrow_ref_mut(cs) = Some(Arena { regions, used: 0, peak: 0, refused: 0 });
    });
    true
}

/// The arena's size and use.
pub fn usage() -> Usage {
    critical_section::with(|cs| match ARENA.borrow_ref(cs).as_ref() {
        Some(arena) => Usage {
            size: arena.regions.iter().map(|(heap, ..)| heap.size()).sum(),
            used: arena.used,
            peak: arena.peak,
            refused: arena.refused,
        },
        None => Usage::default(),
    })
}

/// Starts the peak over from what is in use now (to measure one handshake).
pub fn reset_peak() {
    critical_section::with(|cs| {
        if let Some(arena) = ARENA.borrow_ref_mut(cs).as_mut() {
            arena.peak = arena.used;
        }
    });
}

fn layout(payload: usize) -> Option<Layout> {
    Layout::from_size_align(payload.checked_add(HEADER)?, HEADER).ok()
}

/// Mbed TLS's `calloc`: `count * size` zeroed bytes, or null.
pub(crate) unsafe extern "C" fn calloc(count: usize, size: usize) -> *mut c_void {
    let Some(payload) = count.checked_mul(size) else { return ptr::null_mut() };
    let Some(layout) = layout(payload) else { return ptr::null_mut() };
    let block = critical_section::with(|cs| {
        let mut arena = ARENA.borrow_ref_mut(cs);
        let arena = arena.as_mut()?;
        let taken = arena.regions.iter_mut().find_map(|(heap, ..)| heap.allocate_first_fit(layout).ok());
        match taken {
            Some(block) => {
                arena.used += layout.size();
                arena.peak = arena.peak.max(arena.used);
                Some(block)
            }
            None => {
                arena.refused = arena.refused.saturating_add(1);
                None
            }
        }
    });
    let Some(block) = block else { return ptr::null_mut() };
    let block = block.as_ptr();
    // SAFETY: the block holds HEADER + payload bytes, aligned to HEADER.
    unsafe {
        block.cast::<usize>().write(payload);
        let data = block.add(HEADER);
        data.write_bytes(0, payload);
        data.cast()
    }
}

/// Mbed TLS's `free`: gives back a block from [`calloc`]; null is ignored.
pub(crate) unsafe extern "C" fn free(data: *mut c_void) {
    if data.is_null() {
        return;
    }
    // SAFETY: `data` came from `calloc`, HEADER bytes past the block's
    // start, where its payload size was written.
    let (block, payload) = unsafe {
        let block = data.cast::<u8>().sub(HEADER);
        (block, block.cast::<usize>().read())
    };
    let (Some(block), Some(layout)) = (NonNull::new(block), layout(payload)) else { return };
    critical_section::with(|cs| {
        let mut arena = ARENA.borrow_ref_mut(cs);
        let Some(arena) = arena.as_mut() else { return };
        let at = block.as_ptr() as usize;
        let region = arena.regions.iter_mut().find(|(_, start, len)| (*start..start + len).contains(&at));
        if let Some((heap, ..)) = region {
            // SAFETY: the block and its layout are the ones `calloc` took
            // from this region.
            unsafe { heap.deallocate(block, layout) };
            arena.used = arena.used.saturating_sub(layout.size());
        }
    });
}

/// The C library's `calloc` and `free` on a bare-metal target, which has
/// none: Mbed TLS's defaults name them before [`crate::init`] points it at
/// the arena's own; both are the arena.
#[cfg(target_os = "none")]
mod libc {
    use core::ffi::c_void;

    /// # Safety
    ///
    /// C's `calloc`.
    #[unsafe(no_mangle)]
    pub unsafe extern "C" fn calloc(count: usize, size: usize) -> *mut c_void {
        // SAFETY: the same contract.
        unsafe { super::calloc(count, size) }
    }

    /// # Safety
    ///
    /// C's `free`, of a block from `calloc`.
    #[unsafe(no_mangle)]
    pub unsafe extern "C" fn free(data: *mut c_void) {
        // SAFETY: the same contract.
        unsafe { super::free(data) }
    }
}
