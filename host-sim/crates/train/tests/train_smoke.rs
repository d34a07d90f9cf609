//! Training smoke test on a tiny configuration: the loss must fall, runs must be bit-identical,
//! and saved weights must reload to the same predictions.

use epssn::spec::ModelSpec;
use epssn_train::data::Sample;
use epssn_train::train::Trainer;
use epssn_train::{FloatModel, SplitMix64};

/// Input 32×16, 4 channels at stride 4 (8×4), 4 planes, output 8×8×16.
fn tiny_spec() -> ModelSpec {
    let text = r#"{
      "name": "EPSSN-tiny", "spec_version": 1,
      "sonar": { "system": "ARIS 3000", "beam_table": "ARIS3000_128", "beams": 128, "elevation_half_aperture_deg": 7.0 },
      "range_window": { "r_min_m": 2.0, "r_max_m": 3.536 },
      "input": { "range_bins": 32, "beam_columns": 16 },
      "baseline": { "roll_step_deg": 7.0, "views": 2, "max_views": 3, "lever_arm_m": [0.0, 0.0, 0.0], "pair_tolerance_deg": 0.5 },
      "features": { "channels": 4, "stride": 4 },
      "planes": 4,
      "output": { "elevation_rows": 8, "azimuth_columns": 16, "range_bins": 8 },
      "warp": { "fraction_bits": 8 },
      "feature_net": [
        { "name": "f0", "kind": "conv2d", "in": 1, "out": 4, "kernel": [3, 3], "stride": [2, 2], "padding": [1, 1], "batch_norm": true, "relu": true },
        { "name": "f1", "kind": "conv2d", "in": 4, "out": 4, "kernel": [3, 3], "stride": [1, 1], "padding": [1, 1], "batch_norm": true, "relu": true },
        { "name": "f2", "kind": "conv2d", "in": 4, "out": 4, "kernel": [3, 3], "stride": [2, 2], "padding": [1, 1], "batch_norm": true, "relu": true },
        { "name": "f3", "kind": "conv2d", "in": 4, "out": 4, "kernel": [3, 3], "stride": [1, 1], "padding": [1, 1], "batch_norm": false, "relu": false }
      ],
      "cost_net": [
        { "name": "d1", "kind": "conv3d", "in": 4, "out": 4, "kernel": [3, 3, 3], "stride": [2, 2, 2], "padding": [1, 1, 1], "batch_norm": true, "relu": true },
        { "name": "d2", "kind": "conv3d", "in": 4, "out": 8, "kernel": [3, 3, 3], "stride": [2, 2, 2], "padding": [1, 1, 1], "batch_norm": true, "relu": true },
        { "name": "m0", "kind": "conv3d", "in": 8, "out": 8, "kernel": [3, 3, 3], "stride": [1, 1, 1], "padding": [1, 1, 1], "batch_norm": true, "relu": true },
        { "name": "u1", "kind": "conv_transpose3d", "in": 8, "out": 4, "kernel": [3, 3, 3], "stride": [2, 2, 2], "padding": [1, 1, 1], "output_padding": [1, 1, 1], "batch_norm": true, "relu": true, "skip": "d1" },
        { "name": "u0", "kind": "conv_transpose3d", "in": 4, "out": 4, "kernel": [3, 3, 3], "stride": [2, 2, 2], "padding": [1, 1, 1], "output_padding": [1, 1, 1], "batch_norm": true, "relu": true, "skip": "cost" },
        { "name": "head", "kind": "conv_transpose3d", "in": 4, "out": 1, "kernel": [2, 1, 4], "stride": [2, 1, 4], "padding": [0, 0, 0], "output_padding": [0, 0, 0], "batch_norm": false, "relu": false }
      ],
      "training": { "loss": "masked L1", "lambda": 3.0, "optimizer": "Adam", "lr": 0.001, "lr_halved_at_fraction": 0.5, "batch": 4 }
    }"#;
    epssn_train::parse_spec(text.as_bytes()).unwrap()
}

/// A flat wall at range `d` (target everywhere), seen as a bright band at its range bin in
/// every view, plus deterministic noise.
fn synthetic(count: usize, seed: u64) -> Vec<Sample> {
    let mut rng = SplitMix64::new(seed);
    let (r, w, e, a) = (32usize, 16usize, 8usize, 16usize);
    let (r_min, r_max) = (2.0f32, 3.536f32);
    (0..count)
        .map(|_| {
            let d = 2.05 + 0.4 * rng.unit();
            let bin = ((d - r_min) / (r_max - r_min) * r as f32) as usize;
            let views = (0..2)
                .map(|_| {
                    let mut img = vec![0u8; r * w];
                    for (i, row) in img.chunks_mut(w).enumerate() {
                        for px in row.iter_mut() {
                            let band = if i.abs_diff(bin) <= 1 { 200.0 } else { 10.0 };
                            *px = (band + 30.0 * rng.unit()) as u8;
                        }
                    }
                    img
                })
                .collect();
            Sample {
                views,
                depth: vec![d; e * a],
                mask: vec![1.0; e * a],
                dir: "synthetic".into(),
            }
        })
        .collect()
}

fn train(steps: usize, seed: u64) -> (Trainer, Vec<f32>) {
    let spec = tiny_spec();
    let data = synthetic(16, 7);
    let mut t = Trainer::new(&spec, seed, 2).unwrap();
    let mut losses = vec![t.eval_loss(&data, 4).unwrap()];
    for s in 0..steps {
        let b: Vec<&Sample> = (0..4).map(|i| &data[(s * 4 + i) % data.len()]).collect();
        losses.push(t.step(&b, 1e-2).unwrap());
    }
    (t, losses)
}

#[test]
fn loss_falls_and_runs_repeat_bit_for_bit() {
    let (trainer, mut losses) = train(40, 3);
    // Inference mode (batch norm on running statistics) must have learnt too.
    let data = synthetic(16, 7);
    let eval_before = losses.remove(0);
    let eval_after = trainer.eval_loss(&data, 4).unwrap();
    eprintln!("eval {eval_before} -> {eval_after}; train {losses:?}");
    assert!(
        eval_after < 0.7 * eval_before,
        "inference loss {eval_before} -> {eval_after}"
    );
    let first = losses[..4].iter().sum::<f32>() / 4.0;
    let last = losses[losses.len() - 4..].iter().sum::<f32>() / 4.0;
    assert!(losses.iter().all(|l| l.is_finite()));
    assert!(
        last < 0.7 * first,
        "loss did not fall: first {first}, last {last}: {losses:?}"
    );

    let (_, again) = train(6, 3);
    assert_eq!(
        &losses[..6],
        &again[1..],
        "same seed must give bit-identical losses"
    );

    // Save, reload for inference, and compare with the trainer's own validation-mode forward.
    let dir = tempfile::tempdir().unwrap();
    let tensors = trainer.tensors();
    let names: Vec<&str> = tensors.keys().map(|s| s.as_str()).collect();
    for n in [
        "f0.conv.weight",
        "f0.bn.gamma",
        "f0.bn.running_var",
        "f3.conv.bias",
        "u1.bn.beta",
        "head.conv.weight",
    ] {
        assert!(names.contains(&n), "missing {n} in {names:?}");
    }
    assert!(!names.contains(&"f3.bn.gamma") && !names.contains(&"head.bn.gamma"));
    assert_eq!(
        tensors["u1.conv.weight"].shape,
        vec![8, 4, 3, 3, 3],
        "convT weights are [I][O][k]"
    );
    assert_eq!(
        tensors["d2.conv.weight"].shape,
        vec![8, 4, 3, 3, 3],
        "conv weights are [O][I][k]"
    );
    epssn_train::save_safetensors(
        &dir.path().join(epssn_train::WEIGHTS_FILE),
        &tensors,
        Default::default(),
    )
    .unwrap();
    let spec_json = serde_json::to_vec(&tiny_spec()).unwrap();
    std::fs::write(dir.path().join(epssn_train::SPEC_FILE), spec_json).unwrap();
    let reloaded =
        epssn_train::load_safetensors(&dir.path().join(epssn_train::WEIGHTS_FILE)).unwrap();
    assert_eq!(reloaded, tensors);

    let fm = FloatModel::load(dir.path()).unwrap();
    let sample = &synthetic(1, 99)[0];
    let depth = fm.predict(&sample.views).unwrap();
    assert_eq!(depth.len(), 8 * 16);
    assert!(depth.iter().all(|d| (2.0..=3.536).contains(d)));
    let acts = fm.activations(&sample.views).unwrap();
    let act = |n: &str| {
        acts.iter()
            .find(|a| a.name == n)
            .unwrap_or_else(|| panic!("no {n}"))
    };
    assert_eq!(act("f3").shape, vec![2, 4, 8, 4]);
    assert_eq!(act("cost").shape, vec![1, 4, 4, 8, 4]);
    assert_eq!(act("d1").shape, vec![1, 4, 2, 4, 2]);
    assert_eq!(act("head").shape, vec![1, 1, 8, 8, 16]);
    assert_eq!(act("depth").data, depth, "activations and predict agree");
    assert!(act("f0").data.iter().all(|&v| v >= 0.0), "f0 is after ReLU");
    assert!(
        act("cost").data.iter().all(|&v| v >= 0.0),
        "a variance is never negative"
    );

    // One view = the reference as its own source (the single-view ablation).
    let single = fm.predict(&sample.views[..1]).unwrap();
    assert_eq!(single.len(), depth.len());
}
