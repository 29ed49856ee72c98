//! [`LargeBlockCache`]: a global allocator for a program that frees and asks again for the
//! same large buffers frame after frame (Linux).
//!
//! Why: YOLOX's tensors and packing buffers, tracking's image pyramids and bundle adjustment's
//! matrices (128 KiB to a few MiB) are allocated and freed on every frame. glibc serves such
//! blocks from its heaps once its mmap threshold has risen past them, and the holes they leave
//! between long-lived map data stay resident; mapping each one afresh instead costs a page
//! fault per page. Here a large block is its own mapping, and a freed one waits in a small
//! cache of the freeing thread for the next request: the sizes repeat from frame to frame, so
//! the pages stay faulted in and nothing else fragments around them. Measurements:
//! docs/realtime.md.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::Mutex;

/// Blocks of at least this many bytes get their own mapping (glibc's initial mmap threshold).
pub const LARGE_BLOCK_BYTES: usize = 128 * 1024;
/// The most bytes freed blocks may hold in a thread's cache; beyond it the longest-cached are
/// unmapped. More keeps more pages resident, less faults more of them in again (the trade is
/// measured in docs/realtime.md).
pub const CACHE_BYTES: usize = 16 << 20;
const PAGE: usize = 4096;
/// Slots in the cache (a fixed array: the allocator must not allocate under its own lock).
const SLOTS: usize = 256;

/// The global allocator: [`System`] for blocks under [`LARGE_BLOCK_BYTES`] (and for alignments
/// over a page), anonymous mappings with a cache of freed ones for the others. Declared by the
/// `stillpoint` binary (`#[global_allocator]`); a library leaves the choice to its program.
pub struct LargeBlockCache;

struct Cache {
    /// Free mappings as (length in bytes, address); `len == 0` marks an empty slot.
    blocks: [(usize, usize); SLOTS],
    /// When each slot was filled (`tick` then): the oldest goes first.
    age: [u64; SLOTS],
    tick: u64,
    bytes: usize,
}

/// Caches, one a thread (threads beyond [`SHARDS`] share): a detector's inference frees and
/// asks again for its own sizes, which tracking's buffers must not push out.
const SHARDS: usize = 4;
#[allow(clippy::declare_interior_mutable_const)]
const EMPTY: Mutex<Cache> = Mutex::new(Cache {
    blocks: [(0, 0); SLOTS],
    age: [0; SLOTS],
    tick: 0,
    bytes: 0,
});
static CACHES: [Mutex<Cache>; SHARDS] = [EMPTY; SHARDS];
/// Blocks handed out on a larger mapping than their size asks, as (address, mapping length):
/// any thread may free them.
static LENT: Mutex<[(usize, usize); SLOTS]> = Mutex::new([(0, 0); SLOTS]);
static NEXT_SHARD: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
thread_local! {
    static SHARD: std::cell::Cell<usize> = const { std::cell::Cell::new(usize::MAX) };
}

/// Note that the block at `addr` is a mapping of `len` bytes; false when there is no room.
fn lend_whole(addr: usize, len: usize) -> bool {
    let mut lent = LENT.lock().unwrap_or_else(|e| e.into_inner());
    match lent.iter().position(|l| l.0 == 0) {
        Some(i) => {
            lent[i] = (addr, len);
            true
        }
        None => false,
    }
}

/// The mapping length of the block at `addr` when it was lent whole (forgotten then).
fn returned(addr: usize) -> Option<usize> {
    let mut lent = LENT.lock().unwrap_or_else(|e| e.into_inner());
    let i = lent.iter().position(|l| l.0 == addr)?;
    Some(std::mem::take(&mut lent[i]).1)
}

fn is_large(layout: &Layout) -> bool {
    layout.size() >= LARGE_BLOCK_BYTES && layout.align() <= PAGE
}

/// The mapping for a block of `size` bytes: rounded up to a quarter of its power of two (so a
/// buffer that grows or shrinks a little still finds its mapping again), whole pages.
fn mapping_len(size: usize) -> usize {
    let step = ((1usize << (usize::BITS - 1 - size.leading_zeros())) / 4).max(PAGE);
    size.div_ceil(step) * step
}

/// This thread's cache.
fn lock() -> std::sync::MutexGuard<'static, Cache> {
    let shard = SHARD.with(|s| {
        if s.get() == usize::MAX {
            s.set(NEXT_SHARD.fetch_add(1, std::sync::atomic::Ordering::Relaxed) % SHARDS);
        }
        s.get()
    });
    // A panic under the lock leaves the cache consistent (every update is one assignment).
    CACHES[shard].lock().unwrap_or_else(|e| e.into_inner())
}

/// A mapping of `len` bytes made from this thread's cache, keeping its pages: the smallest
/// cached block that holds `len` (lent whole when at most twice `len`, else split, its tail
/// staying cached), else the largest one grown (`mremap`); `None` when the cache is empty.
fn take_cached(len: usize) -> Option<*mut u8> {
    let (addr, had) = {
        let mut cache = lock();
        // the smallest block that holds `len`, else the largest that does not
        let fits = (0..SLOTS)
            .filter(|&i| cache.blocks[i].0 >= len)
            .min_by_key(|&i| cache.blocks[i].0);
        let slot = fits.or_else(|| {
            (0..SLOTS)
                .filter(|&i| cache.blocks[i].0 != 0)
                .max_by_key(|&i| cache.blocks[i].0)
        })?;
        let (had, addr) = cache.blocks[slot];
        if had > len && !(had <= 2 * len && lend_whole(addr, had)) {
            // the head goes, the tail stays cached: pages are never given back to be faulted
            // in again (a mapping may be unmapped piece by piece)
            cache.blocks[slot] = (had - len, addr + len);
            cache.bytes -= len;
            return Some(addr as *mut u8);
        }
        cache.blocks[slot] = (0, 0);
        cache.bytes -= had;
        (addr, had)
    };
    if had >= len {
        // exactly its size, or lent whole: its deallocation finds its length in `LENT`
        return Some(addr as *mut u8);
    }
    // SAFETY: a mapping of `had` bytes this allocator owns, grown (moved if need be) to `len`:
    // its faulted pages come along, only the new tail is fresh.
    let p = unsafe { libc::mremap(addr as *mut libc::c_void, had, len, libc::MREMAP_MAYMOVE) };
    if p == libc::MAP_FAILED {
        // SAFETY: the same mapping, unchanged by the failed mremap.
        unsafe { libc::munmap(addr as *mut libc::c_void, had) };
        return None;
    }
    Some(p.cast())
}

/// Keep the mapping at `ptr` for a later request, unmapping the longest-cached ones when the
/// cache would hold more than [`CACHE_BYTES`] (or the block itself when it is larger).
unsafe fn release(ptr: *mut u8, len: usize) {
    let mut evicted = [(0usize, 0usize); SLOTS];
    let mut n = 0;
    {
        let len = returned(ptr as usize).unwrap_or(len);
        let mut cache = lock();
        if len <= CACHE_BYTES {
            cache.tick += 1;
            let tick = cache.tick;
            while cache.bytes + len > CACHE_BYTES || cache.blocks.iter().all(|b| b.0 != 0) {
                let Some(oldest) = (0..SLOTS)
                    .filter(|&i| cache.blocks[i].0 != 0)
                    .min_by_key(|&i| cache.age[i])
                else {
                    break;
                };
                let (l, a) = std::mem::take(&mut cache.blocks[oldest]);
                cache.bytes -= l;
                evicted[n] = (l, a);
                n += 1;
            }
            let slot = cache.blocks.iter().position(|b| b.0 == 0).unwrap_or(0);
            cache.blocks[slot] = (len, ptr as usize);
            cache.age[slot] = tick;
            cache.bytes += len;
        } else {
            evicted[0] = (len, ptr as usize);
            n = 1;
        }
    }
    for &(l, a) in &evicted[..n] {
        // SAFETY: a mapping of `l` bytes this allocator made and no one uses any more.
        unsafe { libc::munmap(a as *mut libc::c_void, l) };
    }
}

fn map(len: usize) -> *mut u8 {
    // SAFETY: a fresh private anonymous mapping; failure is reported as MAP_FAILED.
    let p = unsafe {
        libc::mmap(
            std::ptr::null_mut(),
            len,
            libc::PROT_READ | libc::PROT_WRITE,
            libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
            -1,
            0,
        )
    };
    if p == libc::MAP_FAILED {
        std::ptr::null_mut()
    } else {
        p.cast()
    }
}

// SAFETY: every block is either System's (small, or over-aligned) or a page-aligned mapping of
// `mapping_len(size)` bytes; `Layout` is the same at allocation and deallocation, so
// `is_large` routes each call back to the side that made the block.
unsafe impl GlobalAlloc for LargeBlockCache {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if !is_large(&layout) {
            // SAFETY: forwarded with the caller's layout.
            return unsafe { System.alloc(layout) };
        }
        let len = mapping_len(layout.size());
        take_cached(len).unwrap_or_else(|| map(len))
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if !is_large(&layout) {
            // SAFETY: forwarded with the caller's layout.
            return unsafe { System.alloc_zeroed(layout) };
        }
        let len = mapping_len(layout.size());
        match take_cached(len) {
            Some(p) => {
                // SAFETY: the cached mapping holds `len >= layout.size()` writable bytes.
                unsafe { std::ptr::write_bytes(p, 0, layout.size()) };
                p
            }
            // a fresh mapping is zeroed by the kernel
            None => map(len),
        }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if !is_large(&layout) {
            // SAFETY: `ptr` came from System with this layout.
            return unsafe { System.dealloc(ptr, layout) };
        }
        // SAFETY: `ptr` is a mapping of `mapping_len(layout.size())` bytes made here.
        unsafe { release(ptr, mapping_len(layout.size())) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: the caller guarantees a valid layout for `new_size` at the same alignment.
        let new_layout = unsafe { Layout::from_size_align_unchecked(new_size, layout.align()) };
        match (is_large(&layout), is_large(&new_layout)) {
            // SAFETY: both sides System's, forwarded as given.
            (false, false) => unsafe { System.realloc(ptr, layout, new_size) },
            (true, true) if mapping_len(new_size) == mapping_len(layout.size()) => ptr,
            _ => {
                // SAFETY: a new block from this allocator, the old one's bytes that fit copied
                // into it, then the old one returned with its own layout.
                unsafe {
                    let new = self.alloc(new_layout);
                    if !new.is_null() {
                        std::ptr::copy_nonoverlapping(ptr, new, layout.size().min(new_size));
                        self.dealloc(ptr, layout);
                    }
                    new
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn large_blocks_are_reused_and_keep_their_bytes_until_freed() {
        let a = LargeBlockCache;
        let layout = Layout::from_size_align(LARGE_BLOCK_BYTES * 3 + 5, 64).unwrap();
        unsafe {
            let p = a.alloc(layout);
            assert!(!p.is_null() && (p as usize).is_multiple_of(PAGE));
            std::ptr::write_bytes(p, 7, layout.size());
            a.dealloc(p, layout);
            // the same page count comes back from the cache, zeroed when asked
            let q = a.alloc_zeroed(layout);
            assert!(!q.is_null());
            assert!(
                std::slice::from_raw_parts(q, layout.size())
                    .iter()
                    .all(|&b| b == 0)
            );
            // growing within the mapping keeps the block; past it moves the bytes
            std::ptr::write_bytes(q, 3, layout.size());
            let r = a.realloc(q, layout, layout.size() + 100);
            assert_eq!(r, q);
            let grown = Layout::from_size_align(layout.size() + 100, 64).unwrap();
            let s = a.realloc(r, grown, LARGE_BLOCK_BYTES * 8);
            assert!(
                std::slice::from_raw_parts(s, layout.size())
                    .iter()
                    .all(|&b| b == 3)
            );
            // shrinking under the threshold hands the bytes to System
            let big = Layout::from_size_align(LARGE_BLOCK_BYTES * 8, 64).unwrap();
            let t = a.realloc(s, big, 1000);
            assert!(std::slice::from_raw_parts(t, 1000).iter().all(|&b| b == 3));
            a.dealloc(t, Layout::from_size_align(1000, 64).unwrap());
        }
    }

    #[test]
    fn split_lent_and_grown_blocks_hold_their_whole_size_and_may_be_freed_anywhere() {
        let a = LargeBlockCache;
        let big = Layout::from_size_align(4 << 20, 8).unwrap();
        let small = Layout::from_size_align(LARGE_BLOCK_BYTES, 8).unwrap();
        let lent = Layout::from_size_align(3 << 20, 8).unwrap();
        let huge = Layout::from_size_align(9 << 20, 8).unwrap();
        let fill = |p: *mut u8, l: Layout, v: u8| unsafe {
            assert!(!p.is_null());
            std::ptr::write_bytes(p, v, l.size());
            assert!(
                std::slice::from_raw_parts(p, l.size())
                    .iter()
                    .all(|&b| b == v)
            );
        };
        let blocks = std::thread::spawn(move || unsafe {
            let a = LargeBlockCache;
            let p = a.alloc(big);
            a.dealloc(p, big);
            // from the cached 4 MiB block: a split head, then the tail lent whole or split
            let (s, l) = (a.alloc(small), a.alloc(lent));
            fill(s, small, 1);
            fill(l, lent, 2);
            a.dealloc(s, small);
            // larger than anything cached: the largest grows
            let h = a.alloc(huge);
            fill(h, huge, 3);
            [(s as usize, small), (l as usize, lent), (h as usize, huge)]
        })
        .join()
        .unwrap();
        // freed on another thread than the one that took them
        for (p, l) in &blocks[1..] {
            unsafe { a.dealloc(*p as *mut u8, *l) };
        }
        let again = unsafe { a.alloc(huge) };
        fill(again, huge, 4);
        unsafe { a.dealloc(again, huge) };
    }

    #[test]
    fn the_cache_never_holds_more_than_its_bytes() {
        let a = LargeBlockCache;
        let layout = Layout::from_size_align(4 << 20, 8).unwrap();
        let blocks: Vec<_> = (0..12).map(|_| unsafe { a.alloc(layout) }).collect();
        for p in blocks {
            unsafe { a.dealloc(p, layout) };
        }
        assert!(lock().bytes <= CACHE_BYTES);
    }
}
