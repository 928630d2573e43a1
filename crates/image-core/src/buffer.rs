//! Whole-frame scratch buffers (a 47 MP frame of `f32` is 190 MB).
//!
//! A fresh allocation of that size is mapped lazily by the kernel and every 4 KiB page faults on
//! its first write, about 46,000 faults per frame, which costs more than the pass that fills it
//! (and the faults of parallel writers contend). On Linux [`zeroed_frame`] asks for transparent
//! huge pages on the buffer (`madvise(MADV_HUGEPAGE)`, as numpy does for its large arrays), so
//! the first touch takes ~100 faults of 2 MiB; elsewhere, or where the kernel declines, it is a
//! plain zeroed `Vec`.

/// A zeroed `Vec<f32>` of `n` values whose pages are cheap to first touch (module docs).
pub fn zeroed_frame(n: usize) -> Vec<f32> {
    let v = vec![0.0f32; n];
    #[cfg(target_os = "linux")]
    advise_huge_pages(&v);
    v
}

/// `madvise(MADV_HUGEPAGE)` over the whole 2 MiB-aligned part of `v` (advice only: a failure
/// changes nothing but the speed, so it is ignored).
#[cfg(target_os = "linux")]
fn advise_huge_pages(v: &[f32]) {
    const HUGE: usize = 2 << 20;
    let start = v.as_ptr() as usize;
    let end = start + std::mem::size_of_val(v);
    let (a, b) = (start.next_multiple_of(HUGE), end / HUGE * HUGE);
    if b > a {
        // SAFETY: [a, b) lies inside the live allocation of `v`; MADV_HUGEPAGE only changes how
        // the kernel backs the pages, never their contents.
        unsafe {
            libc::madvise(a as *mut libc::c_void, b - a, libc::MADV_HUGEPAGE);
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn zeroed_frames_are_zero_of_any_size() {
        for n in [0usize, 1, 1000, 3 << 20] {
            let v = super::zeroed_frame(n);
            assert_eq!(v.len(), n);
            assert!(v.iter().all(|&x| x == 0.0));
        }
    }
}
