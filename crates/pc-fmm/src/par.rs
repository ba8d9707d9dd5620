//! The one home of pc-fmm's unsafe code for parallel writes: rayon workers that each write
//! their own, disjoint blocks of one output slice (a node's expansion, a leaf's outputs, a
//! receiver's run of plan tasks).
//!
//! Safe Rust cannot hand each worker a `&mut` to a block chosen at run time from a shared
//! slice without splitting it up front, which the FMM's passes cannot do cheaply (blocks are
//! picked by tree slot, a pass reads the blocks of the level before). [`Disjoint`] lends the
//! slice to every worker; each access is bounds-checked, and its safety contract is the one
//! thing a caller must uphold: **no two threads touch the same element while one of them
//! writes it**. Every call site states why that holds (each leaf owns its block; a level
//! reads only blocks finished by the level before; a receiver's run is written by the one
//! worker that refined it).
//!
//! (pc-fmm's other `unsafe` code is unchecked indexing in the expansion kernels, `expansion.rs`,
//! with indices from tables built and checked at construction, and the AVX2 arithmetic of
//! `lanes.rs`, entered only after the CPU features were detected.)

use std::marker::PhantomData;
use std::ops::Range;

/// A mutable slice lent to parallel workers that write disjoint blocks of it.
pub(crate) struct Disjoint<'a, T> {
    ptr: *mut T,
    len: usize,
    _slice: PhantomData<&'a mut [T]>,
}

// SAFETY: `Disjoint` is a `&mut [T]` shared under the contract above; sending it to or sharing
// it between threads is sound when `T` may be sent (each element is accessed by one thread at
// a time).
unsafe impl<T: Send> Send for Disjoint<'_, T> {}
unsafe impl<T: Send> Sync for Disjoint<'_, T> {}

impl<'a, T> Disjoint<'a, T> {
    pub(crate) fn new(slice: &'a mut [T]) -> Disjoint<'a, T> {
        Disjoint {
            ptr: slice.as_mut_ptr(),
            len: slice.len(),
            _slice: PhantomData,
        }
    }

    fn check(&self, r: &Range<usize>) {
        assert!(
            r.start <= r.end && r.end <= self.len,
            "block {r:?} outside a slice of {}",
            self.len
        );
    }

    /// The elements `r`, to write.
    ///
    /// # Safety
    /// While the returned slice lives, no other thread reads or writes any element of `r`.
    #[inline]
    #[allow(clippy::mut_from_ref)]
    pub(crate) unsafe fn block_mut(&self, r: Range<usize>) -> &mut [T] {
        self.check(&r);
        // SAFETY: in bounds (checked); exclusive per the caller's contract.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(r.start), r.len()) }
    }

    /// The elements `r`, to read.
    ///
    /// # Safety
    /// While the returned slice lives, no other thread writes any element of `r`.
    #[inline]
    pub(crate) unsafe fn block(&self, r: Range<usize>) -> &[T] {
        self.check(&r);
        // SAFETY: in bounds (checked); not written meanwhile per the caller's contract.
        unsafe { std::slice::from_raw_parts(self.ptr.add(r.start), r.len()) }
    }

    /// Writes `v` at `k` (without reading or dropping what was there).
    ///
    /// # Safety
    /// No other thread reads or writes element `k` meanwhile.
    #[inline]
    pub(crate) unsafe fn write(&self, k: usize, v: T) {
        assert!(k < self.len, "element {k} outside a slice of {}", self.len);
        // SAFETY: in bounds (checked); exclusive per the caller's contract.
        unsafe { self.ptr.add(k).write(v) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn workers_fill_their_own_blocks() {
        let mut v = vec![0u32; 64];
        let d = Disjoint::new(&mut v);
        (0..8usize).into_par_iter().for_each(|b| {
            // SAFETY: block b is this worker's alone.
            let out = unsafe { d.block_mut(b * 8..b * 8 + 8) };
            out.fill(b as u32);
        });
        assert!(v.iter().enumerate().all(|(i, &x)| x == (i / 8) as u32));
    }

    #[test]
    #[should_panic(expected = "outside a slice of 4")]
    fn a_block_past_the_end_panics_instead_of_corrupting() {
        let mut v = vec![0u8; 4];
        let d = Disjoint::new(&mut v);
        // SAFETY: single-threaded.
        let _ = unsafe { d.block(2..6) };
    }
}
