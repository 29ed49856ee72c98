//! The running parts: tracking (per frame), monocular initialisation, local mapping (per
//! keyframe, own thread), loop closing (per keyframe after local mapping, own thread) and the
//! hook through which the dynamic front-end removes keypoints before tracking sees them.

pub mod initializer;
pub mod local_mapping;
pub mod loop_closing;
pub mod tracking;

/// Give the heap that large, short-lived work (a loop correction and its global bundle
/// adjustment, a vocabulary training) freed back to the system. glibc keeps freed memory for
/// reuse, and after such a peak a long run's resident memory stayed ~3 MB higher for good
/// (the soak run, 320x240). Only with glibc; elsewhere nothing.
pub(crate) fn return_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases free heap pages; it touches no live allocation.
    unsafe {
        libc::malloc_trim(0);
    }
}
