//! Ray–primitive intersections of the simulator's ray caster: sphere, box slabs and triangle,
//! with the vector arithmetic they share. The scene's solids (`world`) and a site's mesh
//! (`site`) both cast through them.

pub(crate) fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub(crate) fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub(crate) fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

pub(crate) fn normalise(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt();
    if n > 0.0 {
        [a[0] / n, a[1] / n, a[2] / n]
    } else {
        a
    }
}

/// Hits nearer than this along a ray are ignored (the ray starts at the acoustic centre).
pub(crate) const T_MIN: f64 = 1e-9;

/// Nearest root `t > T_MIN` of a ray against a sphere, with the entry normal.
pub fn ray_sphere(o: [f64; 3], d: [f64; 3], c: [f64; 3], r: f64) -> Option<f64> {
    let oc = sub(o, c);
    let b = dot(oc, d);
    let cc = dot(oc, oc) - r * r;
    let disc = b * b - cc;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    // Numerically stable roots of t² + 2bt + cc = 0.
    let q = if b > 0.0 { -b - s } else { -b + s };
    let (mut t0, mut t1) = (q, if q != 0.0 { cc / q } else { 0.0 });
    if t0 > t1 {
        std::mem::swap(&mut t0, &mut t1);
    }
    if t0 > T_MIN {
        Some(t0)
    } else if t1 > T_MIN {
        Some(t1)
    } else {
        None
    }
}

/// Slab test against the box `[lo, hi]`: (t_enter, t_exit, entry normal).
pub(crate) fn ray_box(
    o: [f64; 3],
    d: [f64; 3],
    lo: [f64; 3],
    hi: [f64; 3],
) -> Option<(f64, f64, [f64; 3])> {
    let mut t0 = f64::NEG_INFINITY;
    let mut t1 = f64::INFINITY;
    let mut normal = [0.0; 3];
    for a in 0..3 {
        if d[a] == 0.0 {
            if o[a] < lo[a] || o[a] > hi[a] {
                return None;
            }
            continue;
        }
        let inv = 1.0 / d[a];
        let (mut ta, mut tb) = ((lo[a] - o[a]) * inv, (hi[a] - o[a]) * inv);
        let mut n = [0.0; 3];
        n[a] = -1.0;
        if ta > tb {
            std::mem::swap(&mut ta, &mut tb);
            n[a] = 1.0;
        }
        if ta > t0 {
            t0 = ta;
            normal = n;
        }
        t1 = t1.min(tb);
    }
    (t0 <= t1).then_some((t0, t1, normal))
}

/// Möller–Trumbore; hits on the edges count (cells share edges, so no ray slips through).
pub(crate) fn ray_triangle(o: [f64; 3], d: [f64; 3], tri: [[f64; 3]; 3]) -> Option<f64> {
    let e1 = sub(tri[1], tri[0]);
    let e2 = sub(tri[2], tri[0]);
    let p = cross(d, e2);
    let det = dot(e1, p);
    if det.abs() < 1e-15 {
        return None;
    }
    let inv = 1.0 / det;
    let s = sub(o, tri[0]);
    let u = dot(s, p) * inv;
    const EPS: f64 = 1e-12;
    if !(-EPS..=1.0 + EPS).contains(&u) {
        return None;
    }
    let q = cross(s, e1);
    let v = dot(d, q) * inv;
    if v < -EPS || u + v > 1.0 + EPS {
        return None;
    }
    let t = dot(e2, q) * inv;
    (t > T_MIN).then_some(t)
}
