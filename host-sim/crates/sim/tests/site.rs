//! Sites from meshes: a procedural tank exported as a mesh renders its analytic ground truth,
//! the three formats give identical samples, the BVH agrees with brute force, and `simulate
//! --site` is deterministic.

use std::path::{Path, PathBuf};

use epssn::config::{DEPTH_COLUMNS, DEPTH_ROWS};
use epssn_sim::groundtruth::front_depth;
use epssn_sim::mesh::{to_bytes, MeshFormat};
use epssn_sim::render::SonarSimParams;
use epssn_sim::scene::{generate, Object, Scene, SceneKind, Split};
use epssn_sim::simulate::{run, simulate_scene, simulate_site_scene, JitterAxes, SimulateOptions};
use epssn_sim::site::{Region, Site};
use epssn_sim::tessellate::scene_mesh;
use epssn_sim::world::World;

/// Writes `scene`'s mesh as `name` in `dir` and loads it as a site.
fn export(scene: &Scene, dir: &Path, name: &str) -> (PathBuf, Site) {
    let path = dir.join(name);
    let format = MeshFormat::from_path(&path).unwrap();
    std::fs::write(&path, to_bytes(&scene_mesh(scene).unwrap(), format)).unwrap();
    let site = Site::load(&path).unwrap();
    (path, site)
}

/// `scene` with its objects replaced by `site`, the pose and the noise seed kept.
fn as_site_scene(scene: &Scene, site: &Site) -> Scene {
    Scene {
        kind: SceneKind::Site,
        objects: vec![Object::Site {
            file: site.file.clone(),
            sha256: site.sha256.clone(),
            triangles: site.mesh.len(),
            reflectivity: 0.6,
        }],
        ..scene.clone()
    }
}

/// Hit pixels of the analytic mask, and those the site matches within 1 mm (mask included).
/// The errors of the site's depth on the analytic mask's pixels (infinite where the site's
/// mask is 0).
fn depth_errors(a: &(Vec<f64>, Vec<bool>), b: &(Vec<f64>, Vec<bool>)) -> Vec<f64> {
    (0..DEPTH_ROWS * DEPTH_COLUMNS)
        .filter(|&i| a.1[i])
        .map(|i| {
            if b.1[i] {
                (a.0[i] - b.0[i]).abs()
            } else {
                f64::INFINITY
            }
        })
        .collect()
}

#[test]
fn an_exported_tank_renders_its_analytic_ground_truth() {
    let dir = tempfile::tempdir().unwrap();
    let mut errors = Vec::new();
    for index in 0..24 {
        let scene = generate(SceneKind::Artificial, Split::Test, 11, index, 2);
        let (_, site) = export(&scene, dir.path(), &format!("tank{index}.stl"));
        let site_scene = as_site_scene(&scene, &site);
        let analytic = front_depth(&scene, &World::new(&scene), 0);
        let meshed = front_depth(
            &site_scene,
            &World::with_site(&site_scene, &site).unwrap(),
            0,
        );
        errors.extend(depth_errors(&analytic, &meshed));
    }
    errors.sort_by(f64::total_cmp);
    let hits = errors.len();
    let close = errors.iter().filter(|e| **e <= 1e-3).count();
    let share = close as f64 / hits as f64;
    let quantile = |q: f64| errors[((hits - 1) as f64 * q) as usize] * 1e6;
    println!(
        "site vs analytic, 24 artificial scenes: {close} of {hits} hit pixels within 1 mm \
         ({:.3} %); error median {:.3} µm, 99th percentile {:.3} µm, largest {:.1} µm, \
         {} above 1 µm",
        100.0 * share,
        quantile(0.5),
        quantile(0.99),
        quantile(1.0),
        errors.iter().filter(|e| **e > 1e-6).count()
    );
    assert!(share >= 0.99, "only {:.3} % within 1 mm", 100.0 * share);

    // The whole sample (views, depth, mask) through the same renderer, every analytic surface
    // given the site's one reflectivity.
    let mut scene = generate(SceneKind::Artificial, Split::Test, 11, 0, 2);
    for o in &mut scene.objects {
        match o {
            Object::Plane { reflectivity, .. }
            | Object::Block { reflectivity, .. }
            | Object::Arch { reflectivity, .. } => *reflectivity = 0.6,
            _ => {}
        }
    }
    let site = Site::load(&dir.path().join("tank0.stl")).unwrap();
    let params = SonarSimParams::default();
    let a = simulate_scene(&scene, &params).unwrap();
    let b = simulate_site_scene(&as_site_scene(&scene, &site), &site, &params).unwrap();
    let same_mask = a.mask.iter().zip(&b.mask).filter(|(x, y)| x == y).count();
    let pixels: usize = a.polar_views.iter().map(Vec::len).sum();
    let differing = a
        .polar_views
        .iter()
        .flatten()
        .zip(b.polar_views.iter().flatten())
        .filter(|(x, y)| x != y)
        .count();
    println!(
        "sample 0: mask equal on {same_mask} of {} pixels, polar views differ on {differing} of \
         {pixels} pixels",
        a.mask.len()
    );
    assert!(same_mask as f64 >= 0.99 * a.mask.len() as f64);
    assert!((differing as f64) < 0.01 * pixels as f64);
}

#[test]
fn the_bvh_agrees_with_brute_force() {
    use rand::{RngExt, SeedableRng};
    let dir = tempfile::tempdir().unwrap();
    let scene = generate(SceneKind::Artificial, Split::Train, 2, 1, 2);
    let (_, site) = export(&scene, dir.path(), "tank.stl");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let o = scene.sonar.position_m;
    let rays: Vec<[f64; 3]> = (0..4000)
        .map(|_| {
            let v = [
                rng.random::<f64>() * 2.0 - 1.0,
                rng.random::<f64>() * 2.0 - 1.0,
                rng.random::<f64>() * 2.0 - 1.0,
            ];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|c| c / n)
        })
        .collect();
    for d in &rays {
        assert_eq!(
            site.mesh.cast(o, *d),
            site.mesh.cast_brute_force(o, *d),
            "ray {d:?}"
        );
    }
    let start = std::time::Instant::now();
    let mut met = 0usize;
    for _ in 0..25 {
        for d in &rays {
            met += site.mesh.cast(o, *d).is_some() as usize;
        }
    }
    let secs = start.elapsed().as_secs_f64();
    println!(
        "BVH first hits: {:.0} rays/s on one thread against {} triangles ({met} hits)",
        (25 * rays.len()) as f64 / secs,
        site.mesh.len()
    );
}

#[test]
fn stl_obj_and_ply_of_one_mesh_give_identical_samples() {
    let dir = tempfile::tempdir().unwrap();
    let scene = generate(SceneKind::Artificial, Split::Train, 4, 2, 2);
    let params = SonarSimParams {
        elevation_rays: 64,
        ..SonarSimParams::default()
    };
    let samples: Vec<_> = ["tank.stl", "tank.obj", "tank.ply"]
        .iter()
        .map(|name| {
            let (_, site) = export(&scene, dir.path(), name);
            let scene =
                epssn_sim::site::generate(&site, &Region::default(), 0.6, Split::Train, 9, 3, 2)
                    .unwrap();
            (
                scene.sonar,
                simulate_site_scene(&scene, &site, &params).unwrap(),
            )
        })
        .collect();
    for (pose, s) in &samples[1..] {
        assert_eq!(*pose, samples[0].0);
        assert_eq!(s.frames, samples[0].1.frames);
        assert_eq!(s.polar_views, samples[0].1.polar_views);
        assert_eq!(s.depth, samples[0].1.depth);
        assert_eq!(s.mask, samples[0].1.mask);
    }
}

fn site_args(site: &Path, region: Option<PathBuf>, out: &Path) -> SimulateOptions {
    SimulateOptions {
        scene: None,
        site: Some(site.to_path_buf()),
        region,
        site_reflectivity: None,
        export_mesh: None,
        whole_tank: false,
        pairs: Some(2),
        seed: 5,
        out: Some(out.to_path_buf()),
        split: Split::Test,
        views: 2,
        no_preview: true,
        params: None,
        pose_jitter_deg: 0.0,
        pose_jitter_axes: JitterAxes::Both,
        fixed_pose: false,
    }
}

/// Every file under `dir`, relative path and bytes, sorted.
fn tree(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push((
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                ));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn simulate_site_is_deterministic_and_records_the_site() {
    let dir = tempfile::tempdir().unwrap();
    let scene = generate(SceneKind::Artificial, Split::Train, 1, 0, 2);
    let (path, site) = export(&scene, dir.path(), "tank.stl");
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    run(&site_args(&path, None, &a)).unwrap();
    run(&site_args(&path, None, &b)).unwrap();
    let (ta, tb) = (tree(&a), tree(&b));
    assert!(ta.len() > 10);
    assert_eq!(ta, tb);
    let s = epssn_sim::dataset::Sample::load(&a.join("test/000001")).unwrap();
    assert_eq!(s.scene.kind, SceneKind::Site);
    assert!(
        matches!(&s.scene.objects[0], Object::Site { file, sha256, .. }
        if file == "tank.stl" && *sha256 == site.sha256)
    );
    assert!(s.mask.iter().any(|m| *m > 0.0));
}

#[test]
fn simulate_site_at_the_analytic_pose_gives_the_analytic_depth() {
    let dir = tempfile::tempdir().unwrap();
    let scene = generate(SceneKind::Artificial, Split::Test, 8, 0, 2);
    let (path, _) = export(&scene, dir.path(), "tank.obj");
    let p = scene.sonar;
    let region = Region {
        x_m: Some([p.position_m[0]; 2]),
        y_m: Some([p.position_m[1]; 2]),
        z_m: Some([p.position_m[2]; 2]),
        tilt_deg: [p.tilt_deg; 2],
        yaw_deg: [p.yaw_deg; 2],
        ..Region::default()
    };
    let region_file = dir.path().join("region.json");
    std::fs::write(&region_file, serde_json::to_string(&region).unwrap()).unwrap();
    let out = dir.path().join("out");
    let mut args = site_args(&path, Some(region_file), &out);
    args.pairs = Some(1);
    run(&args).unwrap();
    let s = epssn_sim::dataset::Sample::load(&out.join("test/000000")).unwrap();
    assert_eq!(s.scene.sonar, p);
    let (depth, mask) = front_depth(&scene, &World::new(&scene), 0);
    let hits = mask.iter().filter(|m| **m).count();
    let close = (0..mask.len())
        .filter(|&i| mask[i] && s.mask[i] == 1.0 && (s.depth[i] as f64 - depth[i]).abs() <= 1e-3)
        .count();
    assert!(close as f64 >= 0.99 * hits as f64, "{close} of {hits}");
}

#[test]
fn a_site_without_a_valid_pose_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let scene = generate(SceneKind::Artificial, Split::Train, 1, 0, 2);
    let (path, site) = export(&scene, dir.path(), "tank.ply");
    // Outside the walls: every pose sees the walls' backs.
    let region = Region {
        x_m: Some([20.0, 21.0]),
        max_attempts: 50,
        ..Region::default()
    };
    let err = epssn_sim::site::generate(&site, &region, 0.6, Split::Train, 1, 0, 2).unwrap_err();
    assert!(err.to_string().contains("none of 50 poses"), "{err}");
    // A broken region file is refused by name.
    let bad = dir.path().join("bad.json");
    std::fs::write(&bad, r#"{"tilt_deg": [30, 10]}"#).unwrap();
    let err = run(&site_args(&path, Some(bad.clone()), &dir.path().join("o"))).unwrap_err();
    assert!(format!("{err:#}").contains("tilt_deg"), "{err:#}");
    std::fs::write(&bad, r#"{"tilt": [10, 30]}"#).unwrap();
    assert!(Region::load(&bad).is_err());
}

/// The shipped tank is what its documented command writes (data/sites/README.md), byte for byte.
#[test]
fn shipped_tank_is_the_whole_tank_export() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tank.stl");
    let args = SimulateOptions {
        scene: Some(SceneKind::Artificial),
        site: None,
        export_mesh: Some(path.clone()),
        whole_tank: true,
        seed: 1,
        out: None,
        ..site_args(Path::new("unused.stl"), None, dir.path())
    };
    run(&args).unwrap();
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../data/sites/tank.stl");
    assert!(std::fs::read(&path).unwrap() == std::fs::read(shipped).unwrap());
}
