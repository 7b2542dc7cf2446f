//! The process allocator's settings for training: mimalloc (the `pipeline` binary's global
//! allocator) keeps the memory a training step frees for the next step.
//!
//! A training step frees and allocates the same large tensors every time. By default mimalloc
//! returns freed memory to the kernel 10 ms later (its `purge_delay`), so every step faults its
//! buffers in again and the kernel zero-fills each page: 13 % of a LibTorch segmenter step was
//! the kernel's `clear_page_erms` (`perf`), and keeping the memory made the flex segmenter step
//! 1,090 ms instead of 1,294 and the LibTorch one about 620 ms instead of 800 (docs/benchmarks.md).
//! The cost: the process keeps its peak memory until it exits.
//!
//! With the `libtorch` feature, mimalloc also replaces `malloc` for the whole process
//! (`libmimalloc-sys/override`), so LibTorch's C++ allocations get the same treatment instead of
//! glibc's, which unmaps every block above its mmap threshold when it is freed.

/// mimalloc v2's `mi_option_purge_delay` (`include/mimalloc.h`; the Rust bindings name no
/// constant for it). The workspace pins mimalloc to v2.
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Tells mimalloc never to return freed memory to the kernel. Call once, first thing in `main`;
/// without mimalloc as the global allocator it changes nothing.
pub fn keep_freed_memory() {
    // SAFETY: `mi_option_set` writes one of mimalloc's global option values (an atomic store);
    // it has no preconditions and any value is valid for the purge delay (-1 = never purge).
    #[allow(unsafe_code)]
    unsafe {
        libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1);
    }
}
