//! The feature cache's pairing on arbitrary frame sequences (seq, roll as raw f32 bits, so NaN,
//! infinities and subnormals appear): no panic, and every view set it returns holds the newest
//! frame and rolls within the tolerance of the baseline steps from it.
#![no_main]

use epssn::config;
use epssn::pairing::FeatureCache;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut cache = Box::new(FeatureCache::new());
    for chunk in data.chunks_exact(9) {
        let seq = u32::from_le_bytes([chunk[0], chunk[1], chunk[2], chunk[3]]);
        let roll = f32::from_bits(u32::from_le_bytes([chunk[4], chunk[5], chunk[6], chunk[7]]));
        let views = 2 + (chunk[8] as usize % config::MAX_VIEWS.max(2));
        let Ok(newest) = cache.insert(seq, roll, |_| Ok::<(), ()>(())) else {
            continue;
        };
        let Some(set) = cache.find(&newest, views) else {
            continue;
        };
        let reference = set.reference().expect("a set has a reference");
        let frames: Vec<_> = core::iter::once(reference).chain(set.sources()).collect();
        assert_eq!(frames.len(), views);
        // The newest frame sits at some view position k; view j is then within the tolerance
        // of newest.roll + (j − k)·step (the rule `find` documents).
        let k = frames
            .iter()
            .position(|f| f.seq == newest.seq && f.slot == newest.slot)
            .expect("the set holds the newest frame");
        for (j, f) in frames.iter().enumerate() {
            let want = f64::from(newest.roll_deg) + (j as f64 - k as f64) * config::ROLL_STEP_DEG;
            assert!((f64::from(f.roll_deg) - want).abs() <= config::PAIR_TOLERANCE_DEG + 1e-9);
            assert!(cache.features(f).is_some());
        }
    }
});
