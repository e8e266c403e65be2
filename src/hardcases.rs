//! The hard-case suite: small triangle soups where float evaluation of the
//! multiplicity is hardest (lights exactly and nearly in planes, slivers,
//! collinear and zero-area triangles, huge offsets and tiny scales, fans,
//! inconsistent winding, duplicates, open boxes), each with explicit lights.
//!
//! Shared by the tests (`tests/hard_cases.rs`) and `svpack bench --accuracy`,
//! so the report measures exactly what the tests check.

use std::fmt::Write;

/// Xorshift generator for the cases (fixed seed: the suite never changes).
struct Rng(u64);
impl Rng {
    fn f(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        ((self.0 >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    }
}

/// A triangle soup as OBJ text (shortest round-tripping f32 text).
pub fn obj(v: &[[f32; 3]], f: &[[usize; 3]]) -> String {
    let mut s = String::new();
    for p in v {
        // {:?} prints the shortest text that reads back as the same f32.
        let _ = writeln!(s, "v {:?} {:?} {:?}", p[0], p[1], p[2]);
    }
    for t in f {
        let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    s
}

/// A grid of `n × n` quads (two triangles each) through `at(i, j)`.
pub fn grid(n: usize, at: impl Fn(f32, f32) -> [f32; 3]) -> (Vec<[f32; 3]>, Vec<[usize; 3]>) {
    let mut v = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            v.push(at(i as f32 / n as f32, j as f32 / n as f32));
        }
    }
    let id = |i: usize, j: usize| j * (n + 1) + i;
    let mut f = Vec::new();
    for j in 0..n {
        for i in 0..n {
            f.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            f.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    (v, f)
}

/// Closed box from a subdivided cube (every face a grid), outward.
pub fn closed_box(n: usize, scale: f32, offset: [f32; 3]) -> (Vec<[f32; 3]>, Vec<[usize; 3]>) {
    let mut v = Vec::new();
    let mut f = Vec::new();
    let tf = |p: [f32; 3]| {
        [
            p[0] * scale + offset[0],
            p[1] * scale + offset[1],
            p[2] * scale + offset[2],
        ]
    };
    // Six faces as maps from (s, t) in [0,1]² with outward orientation.
    let faces: [fn(f32, f32) -> [f32; 3]; 6] = [
        |s, t| [s, t, 1.0],
        |s, t| [t, s, 0.0],
        |s, t| [1.0, s, t],
        |s, t| [0.0, t, s],
        |s, t| [t, 1.0, s],
        |s, t| [s, 0.0, t],
    ];
    for face in faces {
        let (gv, gf) = grid(n, |s, t| tf(face(s, t)));
        let base = v.len();
        v.extend(gv);
        f.extend(gf.iter().map(|t| [t[0] + base, t[1] + base, t[2] + base]));
    }
    (v, f)
}

/// One hard case: a soup and the lights that make it hard.
pub struct Case {
    /// Stable name (also the OBJ file stem).
    pub name: &'static str,
    /// Positions.
    pub v: Vec<[f32; 3]>,
    /// Triangles (0-based).
    pub f: Vec<[usize; 3]>,
    /// Explicit lights (world space).
    pub lights: Vec<[f32; 4]>,
}

/// The whole suite, deterministic.
pub fn cases() -> Vec<Case> {
    let mut rng = Rng(0x9E3779B97F4A7C15);
    let mut out = Vec::new();

    // Many triangles in one axis-aligned plane; lights exactly and nearly in it.
    let (v, f) = grid(12, |s, t| [s * 2.0 - 1.0, t * 2.0 - 1.0, 0.0]);
    out.push(Case {
        name: "plane_axis",
        v,
        f,
        lights: vec![
            [3.0, 0.25, 0.0, 1.0],
            [0.1, 0.2, 0.0, 1.0],
            [0.3, 0.1, 1e-7, 1.0],
            [5.0, -2.0, -1e-7, 1.0],
            [1.0, 0.5, 0.0, 0.0],
            [1.0, 0.5, 1e-7, 0.0],
        ],
    });

    // Tilted plane (rounded per vertex): coplanarity only up to rounding.
    let (v, f) = grid(12, |s, t| [s, t, 0.1 * s + 0.37 * t]);
    out.push(Case {
        name: "plane_tilted",
        v,
        f,
        lights: vec![
            [2.0, 2.0, 0.2 + 0.74, 1.0],
            [-1.0, 0.5, -0.1 + 0.185, 1.0],
            [1.0, 0.0, 0.1, 0.0],
            [0.0, 1.0, 0.37, 0.0],
            [0.5, 0.5, 0.235 + 1e-7, 1.0],
        ],
    });

    // Slivers and needles (aspect ~1e-7), collinear and zero-area triangles.
    let mut v = Vec::new();
    let mut f = Vec::new();
    for i in 0..40 {
        let x = i as f32 * 0.1;
        let b = v.len();
        v.push([x, 0.0, 0.0]);
        v.push([x + 1.0, 0.0, 0.0]);
        v.push([x + 0.5, 1e-7, 1e-7 * rng.f()]); // sliver
        v.push([x + 0.5, 0.0, 0.0]); // collinear with the first two
        v.push([x + 0.2, 1.0, 0.3]);
        v.push([x + 0.2 + 1e-7, 1.0, 0.3]); // needle with the previous
        f.push([b, b + 1, b + 2]);
        f.push([b, b + 1, b + 3]);
        f.push([b + 4, b + 5, b]);
    }
    out.push(Case {
        name: "slivers_collinear",
        v,
        f,
        lights: vec![
            [0.5, 0.0, 0.0, 1.0],
            [10.0, 1e-7, 0.0, 1.0],
            [1.0, 0.0, 0.0, 0.0],
        ],
    });

    // Closed boxes far from the origin and tiny; lights inside, on a vertex, on an edge.
    let (v, f) = closed_box(3, 1.0, [1e6, 1e6, -1e6]);
    out.push(Case {
        name: "offset_1e6",
        v,
        f,
        lights: vec![
            [1e6 + 0.5, 1e6 + 0.5, -1e6 + 0.5, 1.0],
            [1e6, 1e6, -1e6, 1.0],
            [1e6 + 0.5, 1e6, -1e6, 1.0],
            [1e6 + 2.0, 1e6 + 3.0, -1e6 - 1.0, 1.0],
        ],
    });
    let (v, f) = closed_box(3, 1e-5, [0.0, 0.0, 0.0]);
    out.push(Case {
        name: "scaled_1e-5",
        v,
        f,
        lights: vec![
            [0.5e-5, 0.5e-5, 0.5e-5, 1.0],
            [0.0, 0.0, 0.0, 1.0],
            [0.5e-5, 0.0, 0.0, 1.0],
            [1.0, 2.0, 3.0, 1.0],
            [0.0, 0.0, 1.0, 0.0],
        ],
    });

    // Non-manifold fans of 3..150 triangles with random orientation.
    let mut v = Vec::new();
    let mut f = Vec::new();
    for (e, &n) in [3usize, 7, 16, 40, 150].iter().enumerate() {
        let b = v.len();
        let z = e as f32 * 2.0;
        v.push([0.0, 0.0, z]);
        v.push([1.0, 0.0, z]);
        for i in 0..n {
            let a = std::f32::consts::TAU * i as f32 / n as f32;
            v.push([0.5 + 0.1 * rng.f(), a.cos(), z + a.sin()]);
            let t = if rng.f() > 0.0 {
                [b, b + 1, b + 2 + i]
            } else {
                [b + 1, b, b + 2 + i]
            };
            f.push(t);
        }
    }
    out.push(Case {
        name: "fans_3_to_150",
        v,
        f,
        lights: vec![
            [0.5, 0.0, 0.0, 1.0],
            [0.5, 0.0, 8.0, 1.0],
            [1.0, 0.0, 0.0, 0.0],
            [0.5, 3.0, 1.0, 1.0],
        ],
    });

    // Inconsistent winding, duplicates, back-to-back and coplanar overlapping triangles.
    let (mut v, mut f) = closed_box(2, 1.0, [0.0; 3]);
    for t in f.iter_mut().step_by(3) {
        t.swap(0, 1);
    }
    let dups: Vec<[usize; 3]> = f.iter().step_by(5).copied().collect();
    for t in dups {
        f.push(t);
        f.push([t[1], t[0], t[2]]);
    }
    let b = v.len();
    v.extend([
        [0.1, 0.1, 1.0],
        [0.9, 0.2, 1.0],
        [0.3, 0.8, 1.0],
        [0.2, 0.15, 1.0],
        [0.7, 0.9, 1.0],
    ]);
    f.push([b, b + 1, b + 2]);
    f.push([b + 3, b + 4, b + 1]);
    out.push(Case {
        name: "winding_dups_overlaps",
        v,
        f,
        lights: vec![
            [0.5, 0.5, 0.5, 1.0],
            [0.5, 0.5, 1.0, 1.0],
            [0.5, 0.5, 3.0, 1.0],
            [0.0, 0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0, 0.0],
        ],
    });

    // Open mesh: a box without its top, light inside the opening.
    let (v, f) = closed_box(3, 1.0, [0.0; 3]);
    let f: Vec<[usize; 3]> = f
        .into_iter()
        .filter(|t| !t.iter().all(|&i| v[i][2] == 1.0))
        .collect();
    out.push(Case {
        name: "open_box",
        v,
        f,
        lights: vec![
            [0.5, 0.5, 1.0, 1.0],
            [0.5, 0.5, 0.5, 1.0],
            [0.0, 0.0, 1.0, 1.0],
            [0.0, 0.0, -1.0, 0.0],
        ],
    });
    out
}
