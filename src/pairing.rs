//! Pairing frames by roll on the device: a bounded queue of cached feature maps
//! `(seq, roll, features)`. A new frame forms a view set with cached frames whose rolls are
//! the new frame's plus or minus multiples of [`config::ROLL_STEP_DEG`], each within
//! [`config::PAIR_TOLERANCE_DEG`]; the lowest roll is the reference and view k sits at
//! reference + k · step (the warp tables' convention). Rolls are compared as reported,
//! without wrap-around at ±180°.

use crate::config;

/// Feature maps the device keeps for pairing.
pub const CACHE_SLOTS: usize = config::MAX_VIEWS;

/// Metadata of one cached feature map.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CachedFrame {
    /// The frame's sequence number.
    pub seq: u32,
    /// The frame's roll, degrees.
    pub roll_deg: f32,
    /// Index of its features in the storage.
    pub slot: usize,
}

/// Frames of one depth map: the reference first, then view 1, view 2.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewSet {
    /// The frames, reference first.
    pub frames: heapless::Vec<CachedFrame, { config::MAX_VIEWS }>,
}

impl ViewSet {
    /// The reference frame.
    pub fn reference(&self) -> Option<&CachedFrame> {
        self.frames.first()
    }

    /// The source frames, view 1 first.
    pub fn sources(&self) -> &[CachedFrame] {
        self.frames.get(1..).unwrap_or(&[])
    }
}

/// A FIFO of cached feature maps: the oldest is evicted when a new frame arrives and the
/// cache is full. Feature storage is a fixed array so that the features are computed in
/// place (no 8 KiB copies through the stack); the heapless queue holds which slot is which.
pub struct FeatureCache {
    queue: heapless::Deque<CachedFrame, CACHE_SLOTS>,
    features: [[i8; config::FEATURE_LEN]; CACHE_SLOTS],
}

impl Default for FeatureCache {
    fn default() -> Self {
        Self::new()
    }
}

impl FeatureCache {
    /// An empty cache.
    pub const fn new() -> Self {
        Self {
            queue: heapless::Deque::new(),
            features: [[0; config::FEATURE_LEN]; CACHE_SLOTS],
        }
    }

    /// Cached frames, oldest first.
    pub fn frames(&self) -> impl Iterator<Item = &CachedFrame> {
        self.queue.iter()
    }

    /// Number of cached frames.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    /// True when nothing is cached.
    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    /// Forgets every cached frame.
    pub fn clear(&mut self) {
        self.queue.clear();
    }

    /// Features of a cached frame.
    pub fn features(&self, frame: &CachedFrame) -> Option<&[i8; config::FEATURE_LEN]> {
        self.features.get(frame.slot)
    }

    /// Caches a new frame: evicts the oldest if full, then `compute` fills the features in
    /// place. If `compute` fails the frame is not cached (an evicted frame stays evicted).
    pub fn insert<E>(
        &mut self,
        seq: u32,
        roll_deg: f32,
        compute: impl FnOnce(&mut [i8; config::FEATURE_LEN]) -> Result<(), E>,
    ) -> Result<CachedFrame, E> {
        if self.queue.is_full() {
            let _ = self.queue.pop_front();
        }
        // The lowest slot no queued frame uses; one exists since the queue is not full.
        let slot = (0..CACHE_SLOTS)
            .find(|s| self.queue.iter().all(|f| f.slot != *s))
            .unwrap_or(0);
        let storage = &mut self.features[slot];
        compute(storage)?;
        let frame = CachedFrame {
            seq,
            roll_deg,
            slot,
        };
        // Cannot fail: a slot was freed above.
        let _ = self.queue.push_back(frame);
        Ok(frame)
    }

    /// The newest cached frame whose roll is `roll` within the tolerance, if any.
    fn near(&self, roll: f64, tolerance: f64) -> Option<CachedFrame> {
        self.queue
            .iter()
            .filter(|f| (f64::from(f.roll_deg) - roll).abs() <= tolerance)
            .max_by_key(|f| f.seq)
            .copied()
    }

    /// A view set of `views` frames (2 or 3) that includes `newest`, with the configured
    /// step and tolerance; see [`FeatureCache::find_with`].
    pub fn find(&self, newest: &CachedFrame, views: usize) -> Option<ViewSet> {
        self.find_with(
            newest,
            views,
            config::ROLL_STEP_DEG,
            config::PAIR_TOLERANCE_DEG,
        )
    }

    /// A view set of `views` frames that includes `newest` at some view position k: the
    /// reference roll is `newest.roll − k·step` and every other view j is the newest cached
    /// frame within `tolerance` of `reference + j·step`. Positions are tried from k = 0 up,
    /// so a frame first serves as a reference for higher rolls already cached. `None` when
    /// no set exists or `views` is not in 2..=MAX_VIEWS.
    pub fn find_with(
        &self,
        newest: &CachedFrame,
        views: usize,
        step: f64,
        tolerance: f64,
    ) -> Option<ViewSet> {
        if !(2..=config::MAX_VIEWS).contains(&views) || !newest.roll_deg.is_finite() {
            return None;
        }
        let roll = f64::from(newest.roll_deg);
        'position: for k in 0..views {
            let reference = roll - k as f64 * step;
            let mut frames = heapless::Vec::new();
            for j in 0..views {
                let frame = if j == k {
                    *newest
                } else {
                    match self.near(reference + j as f64 * step, tolerance) {
                        Some(f) if f.seq != newest.seq => f,
                        _ => continue 'position,
                    }
                };
                // Cannot fail: at most MAX_VIEWS frames.
                let _ = frames.push(frame);
            }
            return Some(ViewSet { frames });
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    fn add(c: &mut FeatureCache, seq: u32, roll: f32) -> CachedFrame {
        c.insert(seq, roll, |f| {
            f.fill(seq as i8);
            Ok::<(), ()>(())
        })
        .unwrap()
    }

    fn seqs(v: &ViewSet) -> Vec<u32> {
        v.frames.iter().map(|f| f.seq).collect()
    }

    #[test]
    fn pairs_by_roll_lower_roll_is_reference() {
        let mut c = FeatureCache::new();
        let a = add(&mut c, 1, 0.0);
        assert_eq!(c.find(&a, 2), None);
        let b = add(&mut c, 2, 7.2);
        assert_eq!(seqs(&c.find(&b, 2).unwrap()), [1, 2]);
        // A frame below a cached one becomes the reference.
        let mut c = FeatureCache::new();
        add(&mut c, 1, 7.0);
        let b = add(&mut c, 2, -0.3);
        let set = c.find(&b, 2).unwrap();
        assert_eq!(seqs(&set), [2, 1]);
        assert_eq!(set.reference().unwrap().seq, 2);
        assert_eq!(set.sources().len(), 1);
        // Features stay with their frame.
        assert!(c.features(&set.frames[1]).unwrap().iter().all(|&v| v == 1));
        assert!(c.features(&set.frames[0]).unwrap().iter().all(|&v| v == 2));
    }

    #[test]
    fn tolerance_is_respected() {
        let mut c = FeatureCache::new();
        add(&mut c, 1, 0.0);
        let tol = config::PAIR_TOLERANCE_DEG as f32;
        let b = add(&mut c, 2, config::ROLL_STEP_DEG as f32 + tol * 1.5);
        assert_eq!(c.find(&b, 2), None);
        let b = add(&mut c, 3, config::ROLL_STEP_DEG as f32 + tol * 0.5);
        assert_eq!(seqs(&c.find(&b, 2).unwrap()), [1, 3]);
        // Same roll never pairs with itself or a twin.
        let mut c = FeatureCache::new();
        add(&mut c, 1, 7.0);
        let b = add(&mut c, 2, 7.0);
        assert_eq!(c.find(&b, 2), None);
        let nan = add(&mut c, 3, f32::NAN);
        assert_eq!(c.find(&nan, 2), None);
    }

    #[test]
    fn three_views_and_eviction() {
        let mut c = FeatureCache::new();
        add(&mut c, 1, 0.0);
        let b = add(&mut c, 2, 7.0);
        assert_eq!(c.find(&b, 3), None);
        let d = add(&mut c, 3, 14.0);
        assert_eq!(seqs(&c.find(&d, 3).unwrap()), [1, 2, 3]);
        assert_eq!(seqs(&c.find(&d, 2).unwrap()), [2, 3]);
        // Full: the next frame evicts seq 1 and takes its slot.
        let e = add(&mut c, 4, 0.1);
        assert_eq!(c.len(), CACHE_SLOTS);
        assert_eq!(e.slot, 0);
        assert!(c.frames().all(|f| f.seq != 1));
        assert_eq!(seqs(&c.find(&e, 3).unwrap()), [4, 2, 3]);
        assert!(c.features(&e).unwrap().iter().all(|&v| v == 4));
        assert_eq!(c.find(&e, 1), None);
        assert_eq!(c.find(&e, config::MAX_VIEWS + 1), None);
    }

    #[test]
    fn newest_duplicate_roll_wins_and_failed_compute_is_not_cached() {
        let mut c = FeatureCache::new();
        add(&mut c, 1, 0.0);
        add(&mut c, 2, 0.2);
        let x = add(&mut c, 3, 7.0);
        assert_eq!(seqs(&c.find(&x, 2).unwrap()), [2, 3]);
        let r: Result<CachedFrame, &str> = c.insert(4, 14.0, |_| Err("model"));
        assert_eq!(r, Err("model"));
        assert!(c.frames().all(|f| f.seq != 4));
        c.clear();
        assert!(c.is_empty());
    }
}
