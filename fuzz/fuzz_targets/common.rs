//! Shared by the fuzz targets: a counting allocator and the round trip.
//!
//! Each target reads the input as one format. When the read succeeds, the
//! document is written back in the same format and read again, which must
//! give the same mesh. The peak heap use during all of that must stay
//! within `PEAK_PER_INPUT_BYTE` times the input size plus `PEAK_SLACK`:
//! no claimed count in a file may drive an allocation beyond what its bytes
//! can back.

use meshsmooth_core::io::{self, Format, ReadLimits};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Heap bytes allowed per input byte.
pub const PEAK_PER_INPUT_BYTE: usize = 64;
/// Heap bytes allowed regardless of the input size.
pub const PEAK_SLACK: usize = 1 << 20;

pub struct Counting;

static CURRENT: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = CURRENT.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) };
        CURRENT.fetch_sub(layout.size(), Ordering::Relaxed);
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            if new_size >= layout.size() {
                let grow = new_size - layout.size();
                let now = CURRENT.fetch_add(grow, Ordering::Relaxed) + grow;
                PEAK.fetch_max(now, Ordering::Relaxed);
            } else {
                CURRENT.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

/// Reads `data` as `format`; on success writes it back and reads it again.
/// Panics when the second read fails or differs, or when the heap grew
/// beyond the bound.
pub fn round_trip(data: &[u8], format: Format) {
    let base = CURRENT.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let limits = ReadLimits {
        max_vertices: 1 << 22,
        max_faces: 1 << 22,
    };
    if let Ok(doc) = io::read(data, format, &limits) {
        let out = io::write(&doc, doc.mesh.positions(), format)
            .unwrap_or_else(|e| panic!("writing back what was read failed: {e}"));
        let again = io::read(&out, format, &limits)
            .unwrap_or_else(|e| panic!("reading back what was written failed: {e}"));
        assert_eq!(again.mesh.num_vertices(), doc.mesh.num_vertices());
        assert_eq!(again.mesh.face_vertices(), doc.mesh.face_vertices());
        assert_eq!(again.num_file_vertices(), doc.num_file_vertices());
    }
    let used = PEAK.load(Ordering::Relaxed).saturating_sub(base);
    let bound = PEAK_PER_INPUT_BYTE * data.len() + PEAK_SLACK;
    assert!(
        used <= bound,
        "peak heap {used} bytes for a {}-byte input (bound {bound})",
        data.len()
    );
}
