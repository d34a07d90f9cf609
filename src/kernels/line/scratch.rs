//! The line engine's scratch ([`LineScratch`]): the laid-out weights, the line buffer, the
//! accumulator rows, and which model layers' weights are kept laid out between calls.

use super::*;

/// The line engine's scratch (expanded weights, line buffer, accumulator rows, about 20 KiB):
/// a kernel call writes every word of it that it reads, so one scratch serves any number of
/// calls and nothing is zeroed per call. The public kernels make one on the stack; the
/// streamed model keeps one in its workspace and passes it to the `*_checked` kernels.
pub struct LineScratch {
    pub(super) wbuf: [u32; WEIGHT_WORDS],
    pub(super) line: [u32; LINE_WORDS],
    pub(super) acc: RowAcc,
    pub(super) kept: KeptWeights,
}

/// The model's layer index ([`crate::kernels::CheckedParams`], which fix its kernel and
/// channels) and the stride (a transposed convolution's layout depends on it).
type WeightsKey = (usize, [usize; 3]);

/// Most layers whose laid-out weights `wbuf` holds side by side (the four feature layers).
const MAX_KEPT: usize = 4;

/// One layer's laid-out weights in `wbuf`.
#[derive(Clone, Copy, Default)]
struct KeptSlot {
    key: WeightsKey,
    /// First word.
    base: usize,
    /// Bit `fz · MAX_STRIDE + fy`: the phase's weights are laid out (bit 0 for a forward
    /// convolution, which has one phase).
    ready: u64,
}

/// Which layers' weights `wbuf` still holds, while the caller allows keeping them
/// ([`LineScratch::keep_weights`]): up to [`MAX_KEPT`] layers packed from word 0 on.
#[derive(Clone, Copy, Default)]
pub(super) struct KeptWeights {
    on: bool,
    slots: [KeptSlot; MAX_KEPT],
    /// Slots in use (`slots[..len]`) and the words they take.
    len: usize,
    used: usize,
}

impl Default for LineScratch {
    fn default() -> Self {
        Self::new()
    }
}

impl LineScratch {
    /// A zeroed scratch.
    pub const fn new() -> Self {
        Self {
            wbuf: [0; WEIGHT_WORDS],
            line: [0; LINE_WORDS],
            acc: [0; 2 * (MAX_POSITIONS + 1)],
            kept: KeptWeights {
                on: false,
                slots: [KeptSlot {
                    key: (0, [0; 3]),
                    base: 0,
                    ready: 0,
                }; MAX_KEPT],
                len: 0,
                used: 0,
            },
        }
    }

    /// From now on, a convolution of a model layer whose weights (same layer, kernel, stride
    /// and channels) were laid out by an earlier call skips laying them out again, as long as
    /// they fit the weight buffer beside the other kept layers' (a transposed convolution's
    /// phase by phase; a forward one's when its output channels form one group). For the
    /// model, which runs a layer many times in pieces (the streamed features, d1 and u0):
    /// the layer is identified by its index in the model
    /// ([`crate::kernels::CheckedParams`] carry it), not by the weights' address, which other
    /// weights could occupy later; parameters not from a model are never kept. The model's
    /// weights must not change until [`LineScratch::forget_weights`].
    pub fn keep_weights(&mut self) {
        // Slots past `len` are never read.
        self.kept.on = true;
        self.kept.len = 0;
        self.kept.used = 0;
    }

    /// Ends [`LineScratch::keep_weights`]: every call lays its weights out again.
    pub fn forget_weights(&mut self) {
        self.kept.on = false;
        self.kept.len = 0;
        self.kept.used = 0;
    }
}

impl KeptWeights {
    /// A transposed convolution's slot ([`KeptWeights::claim`] under `layer`): each `(fz, fy)`
    /// phase at its own offset, when they all fit; the slot and its first word.
    pub(super) fn claim_phases(
        &mut self,
        shape: &ConvShape,
        layer: Option<usize>,
    ) -> (Option<usize>, usize) {
        let [sd, sh, _] = shape.stride;
        let all: usize = (0..sd * sh)
            .map(|f| transposed_phase_words(shape, f / sh, f % sh))
            .sum();
        let slot = self.claim(layer.map(|l| (l, shape.stride)), all, sd, sh);
        (slot, self.base(slot))
    }

    /// The slot that keeps the `words` weight words of `key` (plane and row strides `sd`,
    /// `sh` index its ready bits): the one that holds them already, or a new one after the
    /// kept layers (all forgotten first when the buffer or the slots are full). `None` when
    /// this call cannot keep its weights: it lays them out from word 0, over whatever was
    /// kept, so every kept layer is forgotten.
    #[inline(never)]
    pub(super) fn claim(
        &mut self,
        key: Option<WeightsKey>,
        words: usize,
        sd: usize,
        sh: usize,
    ) -> Option<usize> {
        let keepable = self.on && words <= WEIGHT_WORDS && sd <= MAX_STRIDE && sh <= MAX_STRIDE;
        let Some(key) = key.filter(|_| keepable) else {
            self.len = 0;
            self.used = 0;
            return None;
        };
        let held = self.slots.get(..self.len).unwrap_or(&[]);
        if let Some(i) = held.iter().position(|s| s.key == key) {
            return Some(i);
        }
        if self.len >= MAX_KEPT || self.used + words > WEIGHT_WORDS {
            self.len = 0;
            self.used = 0;
        }
        let slot = self.slots.get_mut(self.len)?;
        *slot = KeptSlot {
            key,
            base: self.used,
            ready: 0,
        };
        self.len += 1;
        self.used += words;
        Some(self.len - 1)
    }

    /// First word of `slot`'s weights (0 without a slot).
    #[inline(always)]
    pub(super) fn base(&self, slot: Option<usize>) -> usize {
        slot.and_then(|i| self.slots.get(i)).map_or(0, |s| s.base)
    }

    /// Whether `slot` holds the weights of ready bit `bit` laid out already; marks them laid
    /// out from now on. Always false without a slot.
    #[inline(always)]
    pub(super) fn laid_out(&mut self, slot: Option<usize>, bit: u64) -> bool {
        match slot.and_then(|i| self.slots.get_mut(i)) {
            Some(s) => {
                let was = s.ready & bit != 0;
                s.ready |= bit;
                was
            }
            None => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kept_weights_pack_layers_and_forget_them_when_overwritten() {
        let mut k = KeptWeights::default();
        let s2 = [2; 3];
        // Not keeping: no slot.
        assert_eq!(k.claim(Some((0, s2)), 100, 2, 2), None);
        k.on = true;
        let a = k.claim(Some((0, s2)), 100, 2, 2);
        let b = k.claim(Some((1, s2)), 200, 2, 2);
        assert_eq!((a, b), (Some(0), Some(1)));
        assert_eq!((k.base(a), k.base(b)), (0, 100));
        // The same layer again: its slot, ready bits kept.
        assert!(!k.laid_out(b, 1));
        assert_eq!(k.claim(Some((1, s2)), 200, 2, 2), b);
        assert!(k.laid_out(b, 1));
        assert!(!k.laid_out(b, 2));
        // Another stride is another layout.
        assert_eq!(k.claim(Some((1, [1; 3])), 200, 1, 1), Some(2));
        // Too big for what is left: everything forgotten, the new layer from word 0.
        let c = k.claim(Some((3, s2)), WEIGHT_WORDS - 100, 2, 2);
        assert_eq!((c, k.base(c)), (Some(0), 0));
        assert!(!k.laid_out(c, 1));
        assert_eq!(k.claim(Some((1, s2)), 200, 2, 2), Some(0));
        assert!(
            !k.laid_out(Some(0), 1),
            "layer 1 was laid out again over layer 3"
        );
        // A call that cannot keep (no layer) writes from word 0: nothing stays kept.
        assert_eq!(k.claim(None, 10, 1, 1), None);
        assert_eq!(k.claim(Some((1, s2)), 200, 2, 2), Some(0));
        assert!(!k.laid_out(Some(0), 1));
        // More layers than slots: the first slot again.
        k.on = true;
        k.len = 0;
        k.used = 0;
        for l in 0..MAX_KEPT {
            assert_eq!(k.claim(Some((l, s2)), 10, 2, 2), Some(l));
        }
        assert_eq!(k.claim(Some((MAX_KEPT, s2)), 10, 2, 2), Some(0));
        assert_eq!(k.base(Some(0)), 0);
        // Too large to keep at all, or strides past the ready bits.
        assert_eq!(k.claim(Some((9, s2)), WEIGHT_WORDS + 1, 2, 2), None);
        assert_eq!(k.claim(Some((9, s2)), 10, MAX_STRIDE + 1, 1), None);
        assert_eq!(k.len, 0);
    }
}
