//! Writes a large, deterministic scene as OBJ, for scaling measurements:
//! `cargo run --release --example scene -- 5000000 scene.obj` writes exactly
//! 5,000,000 triangles (the default count) with f32 coordinates.
//!
//! The scene is a grid of parts cycling through:
//! - manifold parts: tori and spheres, with the UV seam and pole vertices
//!   duplicated as UV-mapped assets have them (welding closes them);
//! - open parts: terrain patches (height fields with a boundary);
//! - non-manifold parts: terrain patches with a fin standing on a row of
//!   grid edges (3 triangles per edge, sharing the grid's own vertices, so
//!   no T-junctions) and "books" of 3 to 6 pages sharing one spine (3 to 6
//!   triangles per spine edge).
//!
//! Part size grows with the requested count (count / 256, between 64 and
//! 32,768 triangles); the remainder is a one-row strip and, for an odd
//! count, one last triangle, so the file has exactly the requested count.
//! No triangle is degenerate after welding. Same count, same bytes.

use std::io::{self, Write};

/// Deterministic generator (SplitMix64).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Triangles written, by kind of part.
#[derive(Default, Debug, Clone, Copy)]
pub struct Counts {
    /// Tori and spheres.
    pub manifold: u64,
    /// Terrain patches and the remainder strip/triangle.
    pub open: u64,
    /// Fins on terrain and books (including the terrain under a fin).
    pub non_manifold: u64,
    /// Parts (OBJ objects).
    pub parts: u64,
}

/// OBJ writer that numbers vertices and places each part in its own cell.
struct Obj<W: Write> {
    out: W,
    /// Vertices written so far (OBJ indices are 1-based).
    vertices: u64,
    /// Offset of the current part, scale and a rotation about y.
    origin: [f64; 3],
    scale: f64,
    rot: (f64, f64),
}

impl<W: Write> Obj<W> {
    fn begin(&mut self, name: &str, part: u64, cells: u64, rng: &mut Rng) -> io::Result<u64> {
        let (i, j, k) = (part % cells, (part / cells) % cells, part / (cells * cells));
        self.origin = [3.0 * i as f64, 3.0 * k as f64, 3.0 * j as f64];
        self.scale = 0.6 + 0.4 * rng.unit();
        let a = std::f64::consts::TAU * rng.unit();
        self.rot = (a.cos(), a.sin());
        writeln!(self.out, "o {name}_{part}")?;
        Ok(self.vertices + 1)
    }

    /// Writes a vertex in part-local coordinates (about [-1, 1]).
    fn v(&mut self, p: [f64; 3]) -> io::Result<()> {
        let (c, s) = self.rot;
        let x = (c * p[0] + s * p[2]) * self.scale + self.origin[0];
        let z = (-s * p[0] + c * p[2]) * self.scale + self.origin[2];
        let y = p[1] * self.scale + self.origin[1];
        writeln!(self.out, "v {} {} {}", x as f32, y as f32, z as f32)?;
        self.vertices += 1;
        Ok(())
    }

    fn f(&mut self, a: u64, b: u64, c: u64) -> io::Result<()> {
        writeln!(self.out, "f {a} {b} {c}")
    }

    /// Quad a-b-c-d (counter-clockwise) as two triangles.
    fn quad(&mut self, a: u64, b: u64, c: u64, d: u64) -> io::Result<()> {
        self.f(a, b, c)?;
        self.f(a, c, d)
    }
}

const TAU: f64 = std::f64::consts::TAU;
const PI: f64 = std::f64::consts::PI;

/// Torus with `u` segments around the ring and `v` around the tube: 2uv
/// triangles. The seam rows/columns are written twice with identical
/// coordinates (angles taken modulo the segment count).
fn torus<W: Write>(o: &mut Obj<W>, base: u64, u: u64, v: u64, r: f64) -> io::Result<u64> {
    for i in 0..=u {
        let a = TAU * (i % u) as f64 / u as f64;
        for j in 0..=v {
            let b = TAU * (j % v) as f64 / v as f64;
            let rr = 0.7 + r * b.cos();
            o.v([rr * a.cos(), r * b.sin(), rr * a.sin()])?;
        }
    }
    let id = |i: u64, j: u64| base + i * (v + 1) + j;
    for i in 0..u {
        for j in 0..v {
            o.quad(id(i, j), id(i, j + 1), id(i + 1, j + 1), id(i + 1, j))?;
        }
    }
    Ok(2 * u * v)
}

/// Sphere with `n` latitude bands and `m` segments: pole fans plus quads,
/// 2m(n − 1) triangles. Pole vertices are duplicated per segment and the
/// seam column is duplicated, all with identical coordinates.
fn sphere<W: Write>(o: &mut Obj<W>, base: u64, n: u64, m: u64) -> io::Result<u64> {
    // Rows 0..=n, each with m + 1 vertices (row 0 and row n are poles).
    for j in 0..=n {
        let th = PI * j as f64 / n as f64;
        let (st, ct) = if j == 0 {
            (0.0, 1.0)
        } else if j == n {
            (0.0, -1.0)
        } else {
            (th.sin(), th.cos())
        };
        for i in 0..=m {
            let ph = TAU * (i % m) as f64 / m as f64;
            o.v([st * ph.cos(), ct, st * ph.sin()])?;
        }
    }
    let id = |i: u64, j: u64| base + j * (m + 1) + i;
    for i in 0..m {
        o.f(id(i, 0), id(i + 1, 1), id(i, 1))?;
        o.f(id(i, n), id(i, n - 1), id(i + 1, n - 1))?;
        for j in 1..n - 1 {
            o.quad(id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1))?;
        }
    }
    Ok(2 * m * (n - 1))
}

/// Height field over w × h quads (2wh triangles, open boundary). With
/// `fin > 0`, a vertical strip of `fin` quad rows stands on grid row h / 2,
/// reusing that row's vertices: each of its w grid edges gets 3 triangles.
fn terrain<W: Write>(
    o: &mut Obj<W>,
    base: u64,
    w: u64,
    h: u64,
    fin: u64,
    rng: &mut Rng,
) -> io::Result<u64> {
    let (f1, f2, p1, p2) = (
        2.0 + 4.0 * rng.unit(),
        2.0 + 4.0 * rng.unit(),
        TAU * rng.unit(),
        TAU * rng.unit(),
    );
    let height = |x: f64, z: f64| 0.15 * (f1 * x + p1).sin() * (f2 * z + p2).cos();
    let coord = |i: u64, n: u64| 2.0 * i as f64 / n as f64 - 1.0;
    for j in 0..=h {
        let z = coord(j, h);
        for i in 0..=w {
            let x = coord(i, w);
            o.v([x, height(x, z), z])?;
        }
    }
    let id = |i: u64, j: u64| base + j * (w + 1) + i;
    for j in 0..h {
        for i in 0..w {
            o.quad(id(i, j), id(i, j + 1), id(i + 1, j + 1), id(i + 1, j))?;
        }
    }
    if fin > 0 {
        let j0 = h / 2;
        let z = coord(j0, h);
        let fbase = base + (w + 1) * (h + 1);
        // Fin rows 1..=fin above the grid row; row 0 is the grid row itself.
        for r in 1..=fin {
            for i in 0..=w {
                let x = coord(i, w);
                o.v([x, height(x, z) + 0.6 * r as f64 / fin as f64, z])?;
            }
        }
        let fid = |i: u64, r: u64| {
            if r == 0 {
                id(i, j0)
            } else {
                fbase + (r - 1) * (w + 1) + i
            }
        };
        for r in 0..fin {
            for i in 0..w {
                o.quad(fid(i, r), fid(i + 1, r), fid(i + 1, r + 1), fid(i, r + 1))?;
            }
        }
    }
    Ok(2 * w * (h + fin))
}

/// `pages` strips of l × h quads sharing one spine of l edges: every spine
/// edge has `pages` triangles on it. 2·pages·l·h triangles.
fn book<W: Write>(o: &mut Obj<W>, base: u64, pages: u64, l: u64, h: u64) -> io::Result<u64> {
    let coord = |i: u64| 2.0 * i as f64 / l as f64 - 1.0;
    for i in 0..=l {
        o.v([coord(i), 0.0, 0.0])?;
    }
    for p in 0..pages {
        let a = PI * (p as f64 + 0.5) / pages as f64;
        for r in 1..=h {
            let d = r as f64 / h as f64;
            for i in 0..=l {
                o.v([coord(i), d * a.sin(), d * a.cos()])?;
            }
        }
    }
    for p in 0..pages {
        let id = |i: u64, r: u64| {
            if r == 0 {
                base + i
            } else {
                base + (l + 1) * (1 + p * h + r - 1) + i
            }
        };
        for r in 0..h {
            for i in 0..l {
                o.quad(id(i, r), id(i + 1, r), id(i + 1, r + 1), id(i, r + 1))?;
            }
        }
    }
    Ok(2 * pages * l * h)
}

fn isqrt(x: u64) -> u64 {
    let mut r = (x as f64).sqrt() as u64;
    while r * r > x {
        r -= 1;
    }
    while (r + 1) * (r + 1) <= x {
        r += 1;
    }
    r
}

/// Writes a scene of exactly `triangles` triangles (at least 1) to `out`.
pub fn write_scene<W: Write>(out: W, triangles: u64) -> io::Result<Counts> {
    let triangles = triangles.max(1);
    let target = (triangles / 256).clamp(64, 32_768);
    let parts_estimate = triangles / target + 2;
    let cells = (1..).find(|c| c * c * c >= parts_estimate).unwrap_or(1);
    let mut o = Obj {
        out,
        vertices: 0,
        origin: [0.0; 3],
        scale: 1.0,
        rot: (1.0, 0.0),
    };
    let mut rng = Rng(0x5eed_5ca1e);
    let mut counts = Counts::default();
    let mut left = triangles;
    let mut part = 0u64;
    writeln!(
        o.out,
        "# svpack scene generator: {triangles} triangles, parts of up to {target}"
    )?;
    while left >= target {
        let t = target;
        let kind = part % 8;
        let written = match kind {
            0 | 3 => {
                let base = o.begin("torus", part, cells, &mut rng)?;
                let v = isqrt(t / 4).max(3);
                let u = (t / (2 * v)).max(3);
                let r = 0.15 + 0.15 * rng.unit();
                let n = torus(&mut o, base, u, v, r)?;
                counts.manifold += n;
                n
            }
            1 | 5 => {
                let base = o.begin("sphere", part, cells, &mut rng)?;
                let n1 = isqrt(t / 4).max(1);
                let m = (t / (2 * n1)).max(3);
                let n = sphere(&mut o, base, n1 + 1, m)?;
                counts.manifold += n;
                n
            }
            2 | 7 => {
                let base = o.begin("terrain", part, cells, &mut rng)?;
                let w = isqrt(t / 2).max(1);
                let h = (t / (2 * w)).max(1);
                let n = terrain(&mut o, base, w, h, 0, &mut rng)?;
                counts.open += n;
                n
            }
            4 => {
                let base = o.begin("terrain_fin", part, cells, &mut rng)?;
                let w = isqrt(t / 2).max(1);
                let rows = (t / (2 * w)).max(3);
                let fin = (rows / 5).max(1);
                let n = terrain(&mut o, base, w, rows - fin, fin, &mut rng)?;
                counts.non_manifold += n;
                n
            }
            _ => {
                let base = o.begin("book", part, cells, &mut rng)?;
                let pages = 3 + rng.next() % 4;
                let l = isqrt(t / (2 * pages)).max(1);
                let h = (t / (2 * pages * l)).max(1);
                let n = book(&mut o, base, pages, l, h)?;
                counts.non_manifold += n;
                n
            }
        };
        debug_assert!(written <= t);
        left -= written;
        part += 1;
        if written == 0 {
            break;
        }
    }
    if left >= 2 {
        let base = o.begin("strip", part, cells, &mut rng)?;
        let n = terrain(&mut o, base, left / 2, 1, 0, &mut rng)?;
        counts.open += n;
        left -= n;
        part += 1;
    }
    if left == 1 {
        let base = o.begin("triangle", part, cells, &mut rng)?;
        o.v([0.0, 0.0, 0.0])?;
        o.v([1.0, 0.0, 0.0])?;
        o.v([0.0, 0.0, 1.0])?;
        o.f(base, base + 2, base + 1)?;
        counts.open += 1;
        part += 1;
    }
    counts.parts = part;
    o.out.flush()?;
    Ok(counts)
}

#[allow(dead_code)]
fn main() {
    let mut args = std::env::args().skip(1);
    let n: u64 = match args.next() {
        Some(a) => a.parse().unwrap_or_else(|_| {
            eprintln!("usage: scene [TRIANGLES] [OUT.obj]  (TRIANGLES defaults to 5000000)");
            std::process::exit(2)
        }),
        None => 5_000_000,
    };
    let out = args.next().unwrap_or_else(|| "scene.obj".into());
    let file = std::fs::File::create(&out).unwrap_or_else(|e| {
        eprintln!("cannot create {out}: {e}");
        std::process::exit(1)
    });
    let c = write_scene(io::BufWriter::with_capacity(1 << 20, file), n).unwrap_or_else(|e| {
        eprintln!("cannot write {out}: {e}");
        std::process::exit(1)
    });
    eprintln!(
        "wrote {out}: {} triangles in {} parts ({} manifold, {} open, {} in non-manifold parts)",
        c.manifold + c.open + c.non_manifold,
        c.parts,
        c.manifold,
        c.open,
        c.non_manifold
    );
}
