//! What the encode stage hands to the bottom-up builders: primitives in code order.

/// Primitives sorted by their (Extended) Morton codes. Builders never compute codes themselves, so
/// every bottom-up builder accepts every encoder.
#[derive(Clone, Copy, Debug)]
pub struct SortedCodes<'a> {
    /// Primitive indices in code order (ties broken by primitive index).
    pub order: &'a [u32],
    /// `codes[i]` is the code of `order[i]`; non-decreasing.
    pub codes: &'a [u64],
    /// Meaningful bits; the most significant is bit `code_bits - 1`.
    pub code_bits: u32,
}

impl SortedCodes<'_> {
    /// The number of sorted primitives; panics (naming `builder`) when codes and order differ in
    /// length.
    pub fn len(&self, builder: &str) -> usize {
        assert_eq!(self.codes.len(), self.order.len(), "{builder}: codes and order differ in length");
        self.order.len()
    }
}
