//! Where the solver keeps its per-primitive workspace: [`Heap`] (growable `Vec`s, with the `alloc` feature) or
//! [`Fixed`] (arrays of a capacity fixed at compile time, no allocator needed). A solve with a [`Fixed`] storage
//! refuses a scene of more than its capacity with [`crate::SolveError::TooManyPrimitives`] before touching the
//! workspace, so every push during the solve is within capacity.

use core::fmt::Debug;
use core::ops::{Deref, DerefMut};

/// A growable list of `T`, as much of `Vec`'s interface as the solver uses.
pub trait Buffer<T: Copy>: Deref<Target = [T]> + DerefMut + Clone + Debug {
    /// An empty buffer with room for `n` elements (a hint: a [`Fixed`] buffer always has its capacity).
    fn with_capacity(n: usize) -> Self;
    fn capacity(&self) -> usize;
    fn clear(&mut self);
    /// Appends `value`; the solve only pushes within the capacity it checked ([`Storage::fits`]).
    fn push(&mut self, value: T);
    fn truncate(&mut self, len: usize);
    fn resize(&mut self, len: usize, value: T);
    fn extend_from_slice(&mut self, values: &[T]);
    /// Appends every value of `values` (within capacity, as [`Buffer::push`]).
    fn extend_iter(&mut self, values: impl Iterator<Item = T>);
    /// Makes room for `n` elements in all (grows a [`Heap`] buffer; a [`Fixed`] one already has its capacity).
    fn reserve_total(&mut self, n: usize);
}

/// The solver's element types, which a [`Fixed`] buffer must be able to fill with a default.
pub trait Element: Copy + Default + Debug {}
impl<T: Copy + Default + Debug> Element for T {}

/// A family of buffers, one per element type.
pub trait Storage: Clone + Debug {
    type Buf<T: Element>: Buffer<T>;
    /// Whether a scene of `n` non-directed primitives fits; `None` if it does, else the capacity.
    fn fits(n: usize) -> Option<usize>;
}

/// Growable `Vec`s: the workspace grows to the largest scene seen and is reused after that.
#[cfg(feature = "alloc")]
#[derive(Debug, Clone, Copy, Default)]
pub struct Heap;

#[cfg(feature = "alloc")]
impl Storage for Heap {
    type Buf<T: Element> = alloc::vec::Vec<T>;

    #[inline]
    fn fits(_: usize) -> Option<usize> {
        None
    }
}

#[cfg(feature = "alloc")]
impl<T: Element> Buffer<T> for alloc::vec::Vec<T> {
    fn with_capacity(n: usize) -> Self {
        alloc::vec::Vec::with_capacity(n)
    }
    #[inline]
    fn capacity(&self) -> usize {
        alloc::vec::Vec::capacity(self)
    }
    #[inline]
    fn clear(&mut self) {
        alloc::vec::Vec::clear(self)
    }
    #[inline]
    fn push(&mut self, value: T) {
        alloc::vec::Vec::push(self, value)
    }
    #[inline]
    fn truncate(&mut self, len: usize) {
        alloc::vec::Vec::truncate(self, len)
    }
    #[inline]
    fn resize(&mut self, len: usize, value: T) {
        alloc::vec::Vec::resize(self, len, value)
    }
    #[inline]
    fn extend_from_slice(&mut self, values: &[T]) {
        alloc::vec::Vec::extend_from_slice(self, values)
    }
    #[inline]
    fn extend_iter(&mut self, values: impl Iterator<Item = T>) {
        Extend::extend(self, values)
    }
    fn reserve_total(&mut self, n: usize) {
        self.reserve(n.saturating_sub(self.len()));
    }
}

/// Arrays of `N` elements: no allocator, scenes of at most `N` non-directed primitives.
#[derive(Debug, Clone, Copy, Default)]
pub struct Fixed<const N: usize>;

impl<const N: usize> Storage for Fixed<N> {
    type Buf<T: Element> = FixedVec<T, N>;

    #[inline]
    fn fits(n: usize) -> Option<usize> {
        (n > N).then_some(N)
    }
}

/// A list of at most `N` elements in an array.
#[derive(Debug, Clone, Copy)]
pub struct FixedVec<T, const N: usize> {
    values: [T; N],
    len: usize,
}

impl<T: Element, const N: usize> Default for FixedVec<T, N> {
    fn default() -> Self {
        Self {
            values: [T::default(); N],
            len: 0,
        }
    }
}

impl<T, const N: usize> Deref for FixedVec<T, N> {
    type Target = [T];
    #[inline]
    fn deref(&self) -> &[T] {
        &self.values[..self.len]
    }
}

impl<T, const N: usize> DerefMut for FixedVec<T, N> {
    #[inline]
    fn deref_mut(&mut self) -> &mut [T] {
        &mut self.values[..self.len]
    }
}

impl<T: Element, const N: usize> Buffer<T> for FixedVec<T, N> {
    fn with_capacity(_: usize) -> Self {
        Self::default()
    }
    #[inline]
    fn capacity(&self) -> usize {
        N
    }
    #[inline]
    fn clear(&mut self) {
        self.len = 0;
    }
    /// Panics past `N`, which the solve never reaches: it checks the scene against `N` first.
    #[inline]
    fn push(&mut self, value: T) {
        self.values[self.len] = value;
        self.len += 1;
    }
    #[inline]
    fn truncate(&mut self, len: usize) {
        self.len = self.len.min(len);
    }
    #[inline]
    fn resize(&mut self, len: usize, value: T) {
        if len > self.len {
            self.values[self.len..len].fill(value);
        }
        self.len = len;
    }
    #[inline]
    fn extend_from_slice(&mut self, values: &[T]) {
        self.values[self.len..self.len + values.len()].copy_from_slice(values);
        self.len += values.len();
    }
    #[inline]
    fn extend_iter(&mut self, values: impl Iterator<Item = T>) {
        for value in values {
            self.push(value);
        }
    }
    fn reserve_total(&mut self, _: usize) {}
}
