//! Pairing frames by roll on the device: a bounded queue of cached feature maps
//! `(seq, roll, features)`. A new frame forms a view set with cached frames whose rolls are
//! the new frame's plus or minus multiples of [`config::ROLL_STEP_DEG`], each within
//! [`config::PAIR_TOLERANCE_DEG`]; the lowest roll is the reference and view k sits at
//! reference + k · step (the warp tables' convention). Rolls are compared as reported,
//! without wrap-around at ±180°.
//!
//! The rolls only find candidates. A candidate set whose frames all carry an attitude is then
//! checked by its relative rotation ([`crate::attitude`]): for each source view k, the roll of
//! `q_ref⁻¹ · q_src` must be k · step within [`config::PAIR_TOLERANCE_DEG`] and the tilt of the
//! forward axis at most [`config::PAIR_RESIDUAL_TOLERANCE_DEG`]. Without attitude on a frame
//! the set is accepted by the roll rule alone, and says so ([`Verdict::RollOnly`]).

use crate::attitude::{Attitude, Verdict};
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
    /// The frame's attitude, if the host sent one.
    pub attitude: Option<Attitude>,
    /// Index of its features in the storage.
    pub slot: usize,
}

/// The gate's figures for a candidate view set: those of the source view that failed, or of
/// the one with the largest residual when all passed.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PairCheck {
    /// `seq` of the reference frame.
    pub reference: u32,
    /// `seq` of the source frame the figures are of.
    pub source: u32,
    /// Relative roll, degrees: from the attitudes, or the rotator rolls' difference (roll-only).
    pub roll_deg: f32,
    /// Tilt of the forward axis, degrees; NaN without attitude.
    pub residual_deg: f32,
    /// The decision.
    pub verdict: Verdict,
}

/// Checks source `src` at view position `k` against `reference`.
pub fn check_pair(
    reference: &CachedFrame,
    src: &CachedFrame,
    k: usize,
    step: f64,
    tolerance: f64,
    residual_tolerance: f64,
) -> PairCheck {
    let baseline = k as f64 * step;
    let (roll_deg, residual_deg, verdict) = match (reference.attitude, src.attitude) {
        (Some(a), Some(b)) => {
            let rel = a.relative(&b);
            (
                rel.roll_deg,
                rel.residual_deg,
                rel.check(baseline, tolerance, residual_tolerance),
            )
        }
        _ => {
            // The roll rule: candidates were found by it, so this passes unless NaN.
            let roll = src.roll_deg - reference.roll_deg;
            let ok = (f64::from(roll) - baseline).abs() <= tolerance;
            (
                roll,
                f32::NAN,
                if ok { Verdict::RollOnly } else { Verdict::Roll },
            )
        }
    };
    PairCheck {
        reference: reference.seq,
        source: src.seq,
        roll_deg,
        residual_deg,
        verdict,
    }
}

/// Frames of one depth map: the reference first, then view 1, view 2.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewSet {
    /// The frames, reference first.
    pub frames: heapless::Vec<CachedFrame, { config::MAX_VIEWS }>,
    /// The gate's figures (an accepted verdict).
    pub check: PairCheck,
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
        self.insert_with_attitude(seq, roll_deg, None, compute)
    }

    /// [`FeatureCache::insert`] for a frame with its attitude.
    pub fn insert_with_attitude<E>(
        &mut self,
        seq: u32,
        roll_deg: f32,
        attitude: Option<Attitude>,
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
            attitude,
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

    /// An accepted view set of `views` frames (2 or 3) that includes `newest`, with the
    /// configured step and tolerances; see [`FeatureCache::find_checked`].
    pub fn find(&self, newest: &CachedFrame, views: usize) -> Option<ViewSet> {
        self.find_checked(newest, views)?.ok()
    }

    /// [`FeatureCache::find_with`] with the spec's step and tolerances.
    pub fn find_checked(
        &self,
        newest: &CachedFrame,
        views: usize,
    ) -> Option<Result<ViewSet, PairCheck>> {
        self.find_with(
            newest,
            views,
            config::ROLL_STEP_DEG,
            config::PAIR_TOLERANCE_DEG,
            config::PAIR_RESIDUAL_TOLERANCE_DEG,
        )
    }

    /// Candidate view sets of `views` frames that include `newest` at some view position k:
    /// the reference roll is `newest.roll − k·step` and every other view j is the newest cached
    /// frame within `tolerance` of `reference + j·step`. Positions are tried from k = 0 up, so
    /// a frame first serves as a reference for higher rolls already cached. Each candidate goes
    /// through the gate ([`check_pair`] per source view): the first accepted set is returned,
    /// else the first candidate's rejection. `None` when no candidate exists or `views` is not
    /// in 2..=MAX_VIEWS.
    pub fn find_with(
        &self,
        newest: &CachedFrame,
        views: usize,
        step: f64,
        tolerance: f64,
        residual_tolerance: f64,
    ) -> Option<Result<ViewSet, PairCheck>> {
        if !(2..=config::MAX_VIEWS).contains(&views) || !newest.roll_deg.is_finite() {
            return None;
        }
        let roll = f64::from(newest.roll_deg);
        let mut rejected = None;
        'position: for k in 0..views {
            let reference = roll - k as f64 * step;
            let mut frames: heapless::Vec<CachedFrame, { config::MAX_VIEWS }> =
                heapless::Vec::new();
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
            let Some(first) = frames.first().copied() else {
                continue;
            };
            let mut check: Option<PairCheck> = None;
            for (j, src) in frames.iter().enumerate().skip(1) {
                let c = check_pair(&first, src, j, step, tolerance, residual_tolerance);
                let worse = match check {
                    None => true,
                    Some(prev) => {
                        !c.verdict.accepted()
                            || (prev.verdict.accepted() && c.residual_deg > prev.residual_deg)
                    }
                };
                if worse {
                    check = Some(c);
                }
                if !c.verdict.accepted() {
                    break;
                }
            }
            match check {
                Some(check) if check.verdict.accepted() => {
                    return Some(Ok(ViewSet { frames, check }))
                }
                Some(check) => {
                    rejected.get_or_insert(check);
                }
                None => {}
            }
        }
        rejected.map(Err)
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

    fn add_posed(c: &mut FeatureCache, seq: u32, roll: f32, pitch: f32, yaw: f32) -> CachedFrame {
        let q = Attitude::from_header_deg(yaw, pitch, 0.0, 0.0, 0.0, roll);
        c.insert_with_attitude(seq, roll, q, |_| Ok::<(), ()>(()))
            .unwrap()
    }

    #[test]
    fn gate_accepts_and_rejects_exactly_by_the_tolerances() {
        let step = config::ROLL_STEP_DEG;
        // Residual tolerance 1°: a pure pitch of 0.99° passes, 1.01° does not; a yaw alike.
        for (pitch, yaw, verdict) in [
            (0.0, 0.0, Verdict::Accepted),
            (0.99, 0.0, Verdict::Accepted),
            (1.01, 0.0, Verdict::Residual),
            (0.0, -0.99, Verdict::Accepted),
            (0.0, -1.01, Verdict::Residual),
            (0.7, 0.7, Verdict::Accepted),
            (0.72, 0.72, Verdict::Residual),
        ] {
            let mut c = FeatureCache::new();
            add_posed(&mut c, 1, 0.0, 0.0, 0.0);
            let b = add_posed(&mut c, 2, step as f32, pitch, yaw);
            let got = c.find_with(&b, 2, step, 0.5, 1.0).unwrap();
            let check = match &got {
                Ok(set) => set.check,
                Err(check) => *check,
            };
            assert_eq!(check.verdict, verdict, "pitch {pitch} yaw {yaw}");
            assert_eq!(got.is_ok(), verdict.accepted());
            assert_eq!((check.reference, check.source), (1, 2));
            let want = (pitch * pitch + yaw * yaw).sqrt();
            assert!((check.residual_deg - want).abs() < 0.01, "{check:?}");
            assert!((check.roll_deg - step as f32).abs() < 0.01, "{check:?}");
        }
        // The roll from the attitudes: a platform roll of 0.6° between the pings fails the
        // roll tolerance although the rotator rolls differ by exactly the step.
        let mut c = FeatureCache::new();
        add_posed(&mut c, 1, 0.0, 0.0, 0.0);
        let q = Attitude::from_header_deg(0.0, 0.0, 0.6, 0.0, 0.0, step as f32);
        let b = c
            .insert_with_attitude(2, step as f32, q, |_| Ok::<(), ()>(()))
            .unwrap();
        let check = c.find_with(&b, 2, step, 0.5, 1.0).unwrap().unwrap_err();
        assert_eq!(check.verdict, Verdict::Roll);
        assert!((check.roll_deg - 7.6).abs() < 0.01);
        // `find` returns only accepted sets.
        assert_eq!(c.find(&b, 2), None);
    }

    #[test]
    fn frames_without_attitude_fall_back_to_the_roll_rule() {
        let mut c = FeatureCache::new();
        add_posed(&mut c, 1, 0.0, 3.0, 0.0);
        // The source has no attitude: the 3° pitch of the reference cannot be seen.
        let b = add(&mut c, 2, 7.2);
        let set = c.find_with(&b, 2, 7.0, 0.5, 1.0).unwrap().unwrap();
        assert_eq!(set.check.verdict, Verdict::RollOnly);
        assert!(set.check.residual_deg.is_nan());
        assert!((set.check.roll_deg - 7.2).abs() < 1e-5);
    }

    #[test]
    fn three_views_report_the_worst_source_and_try_other_positions() {
        let mut c = FeatureCache::new();
        add_posed(&mut c, 1, 0.0, 0.0, 0.0);
        add_posed(&mut c, 2, 7.0, 0.3, 0.0);
        let d = add_posed(&mut c, 3, 14.0, 0.0, 0.6);
        let set = c.find_with(&d, 3, 7.0, 0.5, 1.0).unwrap().unwrap();
        assert_eq!(seqs(&set), [1, 2, 3]);
        assert_eq!(set.check.source, 3);
        assert!((set.check.residual_deg - 0.6).abs() < 0.01);
        // The third view tilted 2°: rejected as a three-view set, with its figures.
        let mut c = FeatureCache::new();
        add_posed(&mut c, 1, 0.0, 0.0, 0.0);
        add_posed(&mut c, 2, 7.0, 0.0, 0.0);
        let d = add_posed(&mut c, 3, 14.0, 2.0, 0.0);
        let check = c.find_with(&d, 3, 7.0, 0.5, 1.0).unwrap().unwrap_err();
        assert_eq!((check.source, check.verdict), (3, Verdict::Residual));
        // ... but as a two-view set the newest frame is the reference-less source of 2, and
        // 1 → 2 alone is not a set containing it: the rejection is 2 → 3's.
        let check = c.find_with(&d, 2, 7.0, 0.5, 1.0).unwrap().unwrap_err();
        assert_eq!((check.reference, check.source), (2, 3));
    }
}
