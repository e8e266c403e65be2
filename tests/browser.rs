//! The WebGL 1 reference renderer (web/renderer.js) in a real browser:
//! headless Chromium with SwiftShader renders fixtures and hard cases, and
//!
//! 1. per pixel, the stencil value it leaves (the number of triangles between
//!    the visible point and the light, mod 256) must equal the exact count
//!    computed here: cast the pixel's ray (f64) against the caps triangles and
//!    a ground plane, nudge the visible point towards the camera, count the
//!    triangles the segment to the light crosses with `svpack::exact::meet`.
//!    Left out, and counted separately: pixels within `BAND` pixels of a
//!    change of shadow count or an occlusion edge, or whose segment touches an
//!    edge exactly (a one-pixel shift of an edge is not an error there);
//!    surfaces lying in a plane through the light (side quads z-fight with
//!    them; they get no direct light either way); and the images of
//!    silhouette vertices (see `mark_volume_corners`). Everything else must
//!    match exactly;
//! 2. per record, the multiplicity (sides) and orientation (caps) that the
//!    reference shader code computes on the GPU must equal the CPU
//!    evaluator's (`Strategy::Reference`).
//!
//! Needs node, `web/node_modules` (`cd web && npm ci`) and Chromium
//! (`$SVPACK_CHROMIUM`, default `/usr/bin/chromium`). Without them the test
//! prints why and passes, unless `SVPACK_REQUIRE_BROWSER=1` (CI), where it
//! fails. Images, read-backs, the built files and scenes.json (rerun with
//! `node web/test/render.mjs scenes.json OUT`) go to `target/browser-artifacts/`.

mod common;

use common::{cross, dot, sub};

use rayon::prelude::*;
use serde_json::json;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};
use svpack::evaluate::Strategy;
use svpack::exact::{H, Meet, det4_sign, meet};
use svpack::multiplicity::Light;
use svpack::verify::{Decoded, decode, evaluate};

const WIDTH: usize = 256;
const HEIGHT: usize = 192;
/// Pixels this close (Chebyshev distance) to a change of object, plane or
/// shadow count are not compared.
const BAND: usize = 1;
/// Most of the compared image must lie outside the band.
const MAX_BAND_FRACTION: f64 = 0.15;
/// The browser run must finish within this.
const RENDER_TIMEOUT: Duration = Duration::from_secs(150);

/// Why the browser test cannot run here, if it cannot.
fn missing_prerequisite() -> Option<String> {
    let web = common::root().join("web");
    if Command::new("node").arg("--version").output().is_err() {
        return Some("node is not installed".into());
    }
    if !web.join("node_modules/playwright-core").is_dir() {
        return Some(format!(
            "{} is missing (run `cd web && npm ci`)",
            web.join("node_modules/playwright-core").display()
        ));
    }
    let chromium = chromium_path();
    if !chromium.exists() {
        return Some(format!(
            "Chromium is not at {} (apt-get install chromium, or set SVPACK_CHROMIUM)",
            chromium.display()
        ));
    }
    None
}

fn chromium_path() -> PathBuf {
    std::env::var_os("SVPACK_CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"))
}

/// One rendered view.
struct Scene {
    name: &'static str,
    input: PathBuf,
    build_args: Vec<&'static str>,
    light: Light,
    /// Camera position relative to the model: centre + size · this.
    view: [f64; 3],
}

/// A camera and receiver placed around a model, all values f32 so that the
/// browser (which reads them from JSON) and this test use the same numbers.
#[derive(Clone, Copy)]
struct Camera {
    eye: [f64; 3],
    target: [f64; 3],
    fovy: f64,
    near: f64,
    ground_y: f64,
    ground_c: [f64; 2],
    ground_half: f64,
}

fn f32v(v: f64) -> f64 {
    v as f32 as f64
}

fn camera(lo: [f32; 3], hi: [f32; 3], view: [f64; 3]) -> Camera {
    let c = [0, 1, 2].map(|k| 0.5 * (lo[k] as f64 + hi[k] as f64));
    let size = (0..3)
        .map(|k| hi[k] as f64 - lo[k] as f64)
        .fold(1e-3, f64::max);
    Camera {
        eye: [0, 1, 2].map(|k| f32v(c[k] + size * view[k])),
        target: c.map(f32v),
        fovy: f32v(0.75),
        near: f32v(0.02 * size),
        ground_y: f32v(lo[1] as f64 - 0.25 * size),
        ground_c: [f32v(c[0]), f32v(c[2])],
        ground_half: f32v(6.0 * size),
    }
}

fn normalize(a: [f64; 3]) -> [f64; 3] {
    let l = dot(a, a).sqrt();
    a.map(|v| v / l)
}

/// World-space ray direction through the centre of pixel (x, y), y counted
/// from the bottom row as readPixels returns them; the same camera as
/// renderer.js's lookAt and perspectiveInfinite.
fn pixel_ray(cam: &Camera, x: usize, y: usize) -> [f64; 3] {
    let z = normalize(sub(cam.eye, cam.target));
    let xa = normalize(cross([0.0, 1.0, 0.0], z));
    let ya = cross(z, xa);
    let t = (cam.fovy / 2.0).tan();
    let aspect = WIDTH as f64 / HEIGHT as f64;
    let nx = (2.0 * (x as f64 + 0.5) / WIDTH as f64 - 1.0) * t * aspect;
    let ny = (2.0 * (y as f64 + 0.5) / HEIGHT as f64 - 1.0) * t;
    normalize([0, 1, 2].map(|k| -z[k] + nx * xa[k] + ny * ya[k]))
}

/// Two-sided ray/triangle intersection (Möller–Trumbore), distance along `d`.
fn hit(o: [f64; 3], d: [f64; 3], t: &[[f64; 3]; 3]) -> Option<f64> {
    let e1 = sub(t[1], t[0]);
    let e2 = sub(t[2], t[0]);
    let p = cross(d, e2);
    let det = dot(e1, p);
    if det.abs() < 1e-300 {
        return None;
    }
    let s = sub(o, t[0]);
    let u = dot(s, p) / det;
    let q = cross(s, e1);
    let v = dot(d, q) / det;
    if u < 0.0 || v < 0.0 || u + v > 1.0 {
        return None;
    }
    let dist = dot(e2, q) / det;
    (dist > 0.0).then_some(dist)
}

/// What the CPU predicts for one pixel.
#[derive(Clone, Copy, PartialEq, Debug)]
struct Truth {
    /// 0 nothing, 1 model, 2 ground.
    kind: u8,
    /// Visible triangle (index over all meshes), or ground / nothing.
    tri: u32,
    /// Triangles strictly between the visible point and the light.
    count: i32,
    /// The segment touches an edge or vertex exactly, or starts on a face.
    ambiguous: bool,
    /// The visible triangle's plane contains the light (exactly, in record
    /// space): the point lies on the boundary of the shadow volume, where
    /// side quads coincide with the surface and z-fight. Not compared, like
    /// `samples_on_faces` in `svpack verify`; such a surface gets no direct
    /// light either way (N·L = 0), so shadowed or not looks the same.
    on_volume_face: bool,
    /// The pixel is within half a pixel of the image of a silhouette vertex
    /// (an endpoint of an edge with m != 0), where several volume faces meet
    /// in one point; see [`mark_volume_corners`].
    corner: bool,
}

/// One mesh prepared for ray casting and counting.
struct Mesh {
    decoded: Decoded,
    /// Record-space triangles as homogeneous points (f32 values).
    rec: Vec<[H; 3]>,
    /// World-space triangles.
    world: Vec<[[f64; 3]; 3]>,
    /// Plane group per triangle (exactly coplanar triangles share one).
    group: Vec<u32>,
    /// Record-space plane per triangle, for a conservative pre-test.
    planes: Vec<Plane>,
    light: Light,
}

impl Mesh {
    fn new(decoded: Decoded, world_light: Light) -> Mesh {
        let light = decoded.space.light_to_record(world_light);
        let tri = |t: &[u32; 3]| t.map(|i| decoded.positions[i as usize]);
        let rec: Vec<[H; 3]> = decoded
            .caps
            .iter()
            .map(|t| tri(t).map(|p| [p[0] as f64, p[1] as f64, p[2] as f64, 1.0]))
            .collect();
        let world = decoded
            .caps
            .iter()
            .map(|t| tri(t).map(|p| decoded.space.to_world(p)))
            .collect();
        // Coplanar triangles (exactly, in record space) share a group, so
        // the seam between the two halves of a cube face is no boundary.
        let mut group: Vec<u32> = (0..rec.len() as u32).collect();
        for i in 0..rec.len() {
            for j in 0..i {
                if group[j] == j as u32
                    && (0..3).all(|c| det4_sign([rec[j][0], rec[j][1], rec[j][2], rec[i][c]]) == 0)
                {
                    group[i] = j as u32;
                    break;
                }
            }
        }
        let planes = rec.iter().map(Plane::new).collect();
        Mesh {
            decoded,
            rec,
            world,
            group,
            planes,
            light,
        }
    }
}

/// A triangle's plane in f64, only to skip the exact test where its answer
/// is certain: both ends of the segment far enough on the same side.
struct Plane {
    n: [f64; 3],
    p: [f64; 3],
    /// Error allowance per unit of |n| · distance scale.
    tol: f64,
}

impl Plane {
    fn new(t: &[H; 3]) -> Plane {
        let p = [t[0][0], t[0][1], t[0][2]];
        let e1 = sub([t[1][0], t[1][1], t[1][2]], p);
        let e2 = sub([t[2][0], t[2][1], t[2][2]], p);
        let n = cross(e1, e2);
        let scale = t
            .iter()
            .flat_map(|v| v[..3].iter())
            .fold(1.0f64, |a, v| a.max(v.abs()));
        Plane {
            n,
            p,
            tol: 1e-9 * dot(n, n).sqrt() * scale,
        }
    }

    /// True when `a` and the homogeneous light `l` are certainly strictly on
    /// the same side (so the segment cannot cross the triangle).
    fn same_side(&self, a: [f64; 3], l: H) -> bool {
        let da = dot(self.n, sub(a, self.p));
        // For a directional light the far end is at infinity along l.xyz.
        let dl = if l[3] == 0.0 {
            dot(self.n, [l[0], l[1], l[2]])
        } else {
            dot(self.n, sub([l[0], l[1], l[2]], self.p))
        };
        let tol = self.tol * (1.0 + a.iter().chain(&l[..3]).fold(0.0f64, |m, v| m.max(v.abs())));
        (da > tol && dl > tol) || (da < -tol && dl < -tol)
    }
}

const GROUND: u32 = u32::MAX - 1;
const NOTHING: u32 = u32::MAX;

/// Which visible triangles continue each other on screen: the same
/// triangle, triangles sharing a vertex (a crease or a smooth surface), or
/// coplanar ones. Anything else next to each other is an occlusion edge.
struct Surfaces {
    /// Per triangle over all meshes: mesh, corner ids, plane group.
    tris: Vec<(usize, [u32; 3], u32)>,
}

impl Surfaces {
    fn new(meshes: &[Mesh]) -> Surfaces {
        let mut tris = Vec::new();
        for (mi, m) in meshes.iter().enumerate() {
            for (ids, g) in m.decoded.caps.iter().zip(&m.group) {
                tris.push((mi, *ids, *g));
            }
        }
        Surfaces { tris }
    }

    fn continuous(&self, a: &Truth, b: &Truth) -> bool {
        if a.kind != b.kind || a.count != b.count {
            return false;
        }
        if a.kind != 1 || a.tri == b.tri {
            return true;
        }
        let (ma, ia, ga) = self.tris[a.tri as usize];
        let (mb, ib, gb) = self.tris[b.tri as usize];
        ma == mb && (ga == gb || ia.iter().any(|v| ib.contains(v)))
    }
}

/// The CPU's prediction for every pixel (rows bottom-up).
fn predict(meshes: &[Mesh], cam: &Camera) -> Vec<Truth> {
    let size = meshes
        .iter()
        .flat_map(|m| m.world.iter().flatten())
        .fold(0.0f64, |a, p| {
            a.max(dot(sub(*p, cam.target), sub(*p, cam.target)).sqrt())
        });
    (0..WIDTH * HEIGHT)
        .into_par_iter()
        .map(|i| {
            let d = pixel_ray(cam, i % WIDTH, i / WIDTH);
            let mut best = (f64::INFINITY, 0u8, NOTHING);
            let mut on_volume_face = false;
            let mut first = 0;
            for m in meshes {
                for (i, (t, r)) in m.world.iter().zip(&m.rec).enumerate() {
                    if let Some(dist) = hit(cam.eye, d, t)
                        && dist < best.0
                    {
                        best = (dist, 1, first + i as u32);
                        let l = m.light.map(|v| v as f64);
                        on_volume_face = det4_sign([r[0], r[1], r[2], l]) == 0;
                    }
                }
                first += m.rec.len() as u32;
            }
            if d[1] != 0.0 {
                let dist = (cam.ground_y - cam.eye[1]) / d[1];
                let p = [0, 2].map(|k| cam.eye[k] + dist * d[k]);
                let inside = (p[0] - cam.ground_c[0]).abs() <= cam.ground_half
                    && (p[1] - cam.ground_c[1]).abs() <= cam.ground_half;
                if dist > 0.0 && dist < best.0 && inside {
                    best = (dist, 2, GROUND);
                    on_volume_face = false;
                }
            }
            let (dist, kind, tri) = best;
            if kind == 0 {
                return Truth {
                    kind,
                    tri,
                    count: 0,
                    ambiguous: false,
                    on_volume_face: false,
                    corner: false,
                };
            }
            // The visible point, moved towards the camera: the GPU counts the
            // visible triangle's own volume as if the point were in front of
            // it (its front cap is pushed to the far plane, so it always
            // fails the depth test), which is the truth just in front.
            let nudge = 1e-4 * size;
            let p = [0, 1, 2].map(|k| cam.eye[k] + (dist - nudge) * d[k]);
            let mut count = 0;
            let mut ambiguous = false;
            for m in meshes {
                let o = m.decoded.space.offset;
                let s = m.decoded.space.scale;
                let pr = [0, 1, 2].map(|k| ((p[k] - o[k] as f64) / s[k] as f64) as f32 as f64);
                let a: H = [pr[0], pr[1], pr[2], 1.0];
                let l: H = m.light.map(|v| v as f64);
                for (t, plane) in m.rec.iter().zip(&m.planes) {
                    if plane.same_side(pr, l) {
                        continue;
                    }
                    match meet(a, l, *t) {
                        Meet::Cross(_) => count += 1,
                        Meet::None => {}
                        Meet::AOnTriangle | Meet::Degenerate => ambiguous = true,
                    }
                }
            }
            Truth {
                kind,
                tri,
                count,
                ambiguous,
                on_volume_face,
                corner: false,
            }
        })
        .collect()
}

/// Marks the pixels at the image of every silhouette vertex. There the
/// side quads of two or more silhouette edges meet in a point (and leave it
/// along shared edges to infinity), and rasterisation need not be exact: on
/// SwiftShader a single pixel at such a vertex of the torus was seen counted
/// twice by the sides while the caps were right. These pixels and their
/// `BAND` neighbours are left out and counted separately.
fn mark_volume_corners(truth: &mut [Truth], meshes: &[Mesh], cam: &Camera) {
    let z = normalize(sub(cam.eye, cam.target));
    let xa = normalize(cross([0.0, 1.0, 0.0], z));
    let ya = cross(z, xa);
    let t = (cam.fovy / 2.0).tan();
    let aspect = WIDTH as f64 / HEIGHT as f64;
    for m in meshes {
        let ev = evaluate(&m.decoded, m.light, Strategy::Reference);
        for (b, ms) in m.decoded.buckets.iter().zip(&ev.sides) {
            for (ids, &mult) in b.ids.chunks_exact(2 + b.k).zip(ms) {
                if mult == 0 {
                    continue;
                }
                for &id in &ids[..2] {
                    let p = m.decoded.space.to_world(m.decoded.positions[id as usize]);
                    let v = sub(p, cam.eye);
                    let depth = -dot(v, z);
                    if depth <= 0.0 {
                        continue;
                    }
                    // Pixel coordinates with pixel centres at integers.
                    let px = ((dot(v, xa) / depth / (t * aspect)) + 1.0) / 2.0 * WIDTH as f64 - 0.5;
                    let py = ((dot(v, ya) / depth / t) + 1.0) / 2.0 * HEIGHT as f64 - 0.5;
                    for y in (py - 0.5).ceil() as i64..=(py + 0.5).floor() as i64 {
                        for x in (px - 0.5).ceil() as i64..=(px + 0.5).floor() as i64 {
                            if (0..WIDTH as i64).contains(&x) && (0..HEIGHT as i64).contains(&y) {
                                truth[y as usize * WIDTH + x as usize].corner = true;
                            }
                        }
                    }
                }
            }
        }
    }
}

/// Per-pixel comparison result.
#[derive(Debug, Default, Clone, PartialEq)]
struct Compared {
    /// Pixels showing model or ground, outside the band, compared.
    compared: usize,
    /// Pixels showing model or ground inside the band.
    band: usize,
    /// Of those, pixels whose visible surface lies in a plane through the light.
    on_volume_faces: usize,
    /// Of those, pixels near a silhouette vertex (and not on such a face).
    at_corners: usize,
    /// Compared pixels where the GPU differs (object or stencil).
    mismatches: usize,
    /// Compared pixels in shadow.
    shadowed: usize,
    /// Up to five mismatches, in words.
    examples: Vec<String>,
}

/// Compares the read-back (R = 255 model / 128 ground / 0 nothing, G = 255
/// where stencil != 0, B = stencil) with the prediction.
fn compare(truth: &[Truth], surfaces: &Surfaces, rgba: &[u8]) -> Compared {
    assert_eq!(rgba.len(), 4 * WIDTH * HEIGHT, "read-back size");
    let mut out = Compared::default();
    for y in 0..HEIGHT {
        for x in 0..WIDTH {
            let t = &truth[y * WIDTH + x];
            let near_change = in_band(truth, surfaces, y * WIDTH + x);
            let px = &rgba[4 * (y * WIDTH + x)..4 * (y * WIDTH + x) + 4];
            if near_change {
                if t.kind != 0 {
                    out.band += 1;
                }
                out.on_volume_faces += t.on_volume_face as usize;
                // Attributed to a corner when nothing else explains it.
                if t.kind != 0
                    && !t.on_volume_face
                    && !in_band_without_corners(truth, surfaces, y * WIDTH + x)
                {
                    out.at_corners += 1;
                }
                continue;
            }
            let gpu_kind = match px[0] {
                255 => 1,
                128 => 2,
                0 => 0,
                _ => 255,
            };
            let mut problem = None;
            if gpu_kind != t.kind {
                problem = Some(format!("object {} but expected {}", gpu_kind, t.kind));
            } else if t.kind != 0 {
                out.compared += 1;
                if t.count != 0 {
                    out.shadowed += 1;
                }
                let want = t.count.rem_euclid(256) as u8;
                if px[2] != want || (px[1] != 0) != (want != 0) {
                    problem = Some(format!(
                        "stencil {} (mask {}) but {} triangles lie between the point and the light",
                        px[2], px[1], t.count
                    ));
                }
            }
            if let Some(p) = problem {
                out.mismatches += 1;
                if out.examples.len() < 5 {
                    out.examples
                        .push(format!("pixel ({x}, {y} from bottom): {p}"));
                }
            }
        }
    }
    out
}

/// Compares the GPU's per-record values (caps then buckets, per mesh) with
/// the CPU evaluator; returns the differences in words.
fn compare_multiplicities(meshes: &[Mesh], gpu: &[i8]) -> (usize, Vec<String>) {
    let mut at = 0;
    let mut bad = Vec::new();
    let mut records = 0;
    for (mi, m) in meshes.iter().enumerate() {
        let ev = evaluate(&m.decoded, m.light, Strategy::Reference);
        let parts = std::iter::once(("caps".to_string(), &ev.caps)).chain(
            m.decoded
                .buckets
                .iter()
                .zip(&ev.sides)
                .map(|(b, s)| (format!("sides k={}", b.k), s)),
        );
        for (label, want) in parts {
            for (r, &w) in want.iter().enumerate() {
                records += 1;
                let g = gpu.get(at).copied();
                if g != Some(w) {
                    bad.push(format!("mesh {mi} {label} record {r}: GPU {g:?}, CPU {w}"));
                }
                at += 1;
            }
        }
    }
    if at != gpu.len() {
        bad.push(format!("GPU wrote {} values for {at} records", gpu.len()));
    }
    (records, bad)
}

/// Non-manifold fan: seven fins on the edge (0,0,0)-(0,1,0) standing on
/// nothing, one fin exactly in the plane z = 0 (a hard case for a light in
/// that plane). Short decimals keep the text exact.
fn fan7_obj() -> String {
    let apex = [
        [1.0, 0.5, 0.0],
        [0.5, 0.5, 0.75],
        [-0.25, 0.5, 1.0],
        [-1.0, 0.5, 0.5],
        [-0.75, 0.5, -0.5],
        [0.0, 0.5, -1.0],
        [0.75, 0.5, -0.75],
    ];
    let mut s = String::from("# non-manifold fan: 7 triangles on one edge (tests/browser.rs)\n");
    s += "v 0 0 0\nv 0 1 0\n";
    for a in apex {
        s += &format!("v {} {} {}\n", a[0], a[1], a[2]);
    }
    for i in 0..apex.len() {
        // Alternate the winding: the fan is not orientable anyway.
        if i % 2 == 0 {
            s += &format!("f 1 2 {}\n", i + 3);
        } else {
            s += &format!("f 2 1 {}\n", i + 3);
        }
    }
    s
}

/// A tilted torus (768 triangles, curved: many silhouette edges and self
/// shadowing) and a "book" of five pages on one spine (5 triangles on one
/// edge), the middle page in the plane z = 0.5.
fn torus_book_obj() -> String {
    let mut s = String::from("# torus and a non-manifold book (tests/browser.rs)\n");
    let (n, m, big, small) = (32, 12, 0.8f64, 0.3f64);
    let tilt = 60f64.to_radians();
    for i in 0..n {
        for j in 0..m {
            let (a, b) = (
                std::f64::consts::TAU * i as f64 / n as f64,
                std::f64::consts::TAU * j as f64 / m as f64,
            );
            let (x, y, z) = (
                (big + small * b.cos()) * a.cos(),
                (big + small * b.cos()) * a.sin(),
                small * b.sin(),
            );
            let (y2, z2) = (
                y * tilt.cos() - z * tilt.sin(),
                y * tilt.sin() + z * tilt.cos(),
            );
            s += &format!("v {} {} {}\n", x as f32, (z2 + 1.15) as f32, y2 as f32);
        }
    }
    let id = |i: usize, j: usize| (i % n) * m + (j % m) + 1;
    for i in 0..n {
        for j in 0..m {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            s += &format!("f {a} {b} {c}\nf {a} {c} {d}\n");
        }
    }
    let base = n * m;
    s += "v -1.8 0 0.5\nv -1.8 1.2 0.5\n";
    for k in 0..5 {
        let a = (30.0 * k as f64 - 60.0).to_radians();
        let (x, z) = ((-1.8 + 0.9 * a.cos()) as f32, (0.5 + 0.9 * a.sin()) as f32);
        s += &format!("v {x} 0 {z}\nv {x} 1.2 {z}\n");
        let (p0, p1) = (base + 3 + 2 * k, base + 4 + 2 * k);
        s += &format!(
            "f {} {p0} {p1}\nf {} {p1} {}\n",
            base + 1,
            base + 1,
            base + 2
        );
    }
    s
}

fn scenes(dir: &Path) -> Vec<Scene> {
    let fx = |f: &str| common::root().join("fixtures").join(f);
    let fan = dir.join("fan7.obj");
    std::fs::write(&fan, fan7_obj()).unwrap();
    let torus = dir.join("torus_book.obj");
    std::fs::write(&torus, torus_book_obj()).unwrap();
    let v = [1.3, 1.1, 1.9];
    let mut out = vec![
        Scene {
            name: "cube_point",
            input: fx("cube.obj"),
            build_args: vec![],
            light: [2.5, 3.0, 1.75, 1.0],
            view: v,
        },
        Scene {
            name: "cube_directional",
            input: fx("cube.obj"),
            build_args: vec![],
            light: [0.625, 1.0, 0.375, 0.0],
            view: v,
        },
        // Light exactly in the plane of the +x face: those two triangles
        // have c = 0 and draw nothing.
        Scene {
            name: "cube_light_in_face_plane",
            input: fx("cube.obj"),
            build_args: vec![],
            light: [1.0, 2.5, 2.75, 1.0],
            view: v,
        },
        // Directional light parallel to the x faces.
        Scene {
            name: "cube_directional_parallel",
            input: fx("cube.obj"),
            build_args: vec![],
            light: [0.0, 1.0, 0.5, 0.0],
            view: [1.6, 1.2, 1.2],
        },
        // Point light exactly on a corner (the contract's special case).
        Scene {
            name: "cube_light_on_corner",
            input: fx("cube.obj"),
            build_args: vec![],
            light: [1.0, 1.0, 1.0, 1.0],
            view: v,
        },
        Scene {
            name: "seamed_cube",
            input: fx("seamed_cube.obj"),
            build_args: vec![],
            light: [-1.5, 3.0, 2.0, 1.0],
            view: v,
        },
        Scene {
            name: "two_tets",
            input: fx("two_tets.obj"),
            build_args: vec![],
            light: [1.5, 4.0, 1.0, 1.0],
            view: v,
        },
        Scene {
            name: "mirrored_gltf",
            input: fx("mirrored.gltf"),
            build_args: vec![],
            light: [1.5, 3.5, 2.0, 1.0],
            view: [0.4, 0.9, 1.4],
        },
        Scene {
            name: "fan12",
            input: fx("fan12.obj"),
            build_args: vec![],
            light: [0.5, 3.0, 2.0, 1.0],
            view: v,
        },
        // Non-manifold fan split into chunks of 3 (7 = 3 + 3 + 1), with the
        // light exactly in one fin's plane.
        Scene {
            name: "fan7_split_light_in_fin_plane",
            input: fan.clone(),
            build_args: vec!["--max-mult", "3"],
            light: [2.0, 1.5, 0.0, 1.0],
            view: [1.2, 1.4, 1.8],
        },
        Scene {
            name: "fan7_directional",
            input: fan,
            build_args: vec!["--max-mult", "3"],
            light: [0.5, 1.0, -0.25, 0.0],
            view: [1.2, 1.4, 1.8],
        },
        // The book's middle page lies in the plane z = 0.5, the light too.
        Scene {
            name: "torus_book_light_in_page_plane",
            input: torus.clone(),
            build_args: vec![],
            light: [0.25, 3.0, 0.5, 1.0],
            view: [0.3, 0.8, 1.4],
        },
    ];
    // 16-bit positions (format 2): normalized UNSIGNED_SHORT attributes and
    // the record-space light.
    out.extend([
        Scene {
            name: "two_tets_unorm16",
            input: fx("two_tets.obj"),
            build_args: vec!["--positions", "unorm16"],
            light: [1.5, 4.0, 1.0, 1.0],
            view: v,
        },
        Scene {
            name: "torus_book_unorm16",
            input: torus,
            build_args: vec!["--positions", "unorm16"],
            light: [-2.25, 3.5, 2.5, 1.0],
            view: [0.3, 0.8, 1.4],
        },
        Scene {
            name: "mirrored_unorm16_directional",
            input: fx("mirrored.gltf"),
            build_args: vec!["--positions", "unorm16"],
            light: [0.5, 1.0, 0.25, 0.0],
            view: [0.4, 0.9, 1.4],
        },
    ]);
    out
}

/// Runs render.mjs with a deadline; returns its output on failure. Output
/// goes to a file, not a pipe, so a chatty page can never block it.
fn render(scenes_json: &Path, out: &Path, log: &Path) -> Result<(), String> {
    let log_file = std::fs::File::create(log).map_err(|e| e.to_string())?;
    let mut child = Command::new("node")
        .arg(common::root().join("web/test/render.mjs"))
        .arg(scenes_json)
        .arg(out)
        .env("SVPACK_CHROMIUM", chromium_path())
        .stdout(log_file.try_clone().map_err(|e| e.to_string())?)
        .stderr(log_file)
        .spawn()
        .map_err(|e| format!("cannot start node: {e}"))?;
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().map_err(|e| e.to_string())? {
            break Some(status);
        }
        if start.elapsed() > RENDER_TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let text = || std::fs::read_to_string(log).unwrap_or_default();
    match status {
        Some(s) if s.success() => Ok(()),
        Some(s) => Err(format!("render.mjs failed ({s}):\n{}", text())),
        None => Err(format!(
            "render.mjs did not finish in {RENDER_TIMEOUT:?}:\n{}",
            text()
        )),
    }
}

#[test]
fn renderer_matches_exact_shadows_in_chromium() {
    if let Some(why) = missing_prerequisite() {
        if std::env::var("SVPACK_REQUIRE_BROWSER").is_ok_and(|v| v == "1") {
            panic!("SVPACK_REQUIRE_BROWSER=1 but the browser test cannot run: {why}");
        }
        eprintln!("skipping the browser test: {why}");
        return;
    }
    let start = Instant::now();
    let tmp = tempfile::tempdir().unwrap();
    let artifacts = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .parent()
        .unwrap()
        .join("browser-artifacts");
    let _ = std::fs::remove_dir_all(&artifacts);
    std::fs::create_dir_all(&artifacts).unwrap();

    let scenes = scenes(tmp.path());
    let mut json_scenes = Vec::new();
    let mut prepared = Vec::new();
    for s in &scenes {
        let file = artifacts.join(format!("{}.svpk", s.name));
        common::svpack()
            .arg("build")
            .arg(&s.input)
            .arg("-o")
            .arg(&file)
            .args(&s.build_args)
            .assert()
            .success();
        let f = svpack::format::read_file(&file).unwrap();
        let cam = camera(f.header.bounds_min, f.header.bounds_max, s.view);
        let meshes: Vec<Mesh> = (0..f.header.meshes.len())
            .map(|i| Mesh::new(decode(&f, i), s.light))
            .collect();
        json_scenes.push(json!({
            "name": s.name,
            "file": file,
            "width": WIDTH,
            "height": HEIGHT,
            "eye": cam.eye,
            "target": cam.target,
            "up": [0.0, 1.0, 0.0],
            "fovy": cam.fovy,
            "near": cam.near,
            "light": s.light,
            "ground": {"y": cam.ground_y, "cx": cam.ground_c[0], "cz": cam.ground_c[1], "half": cam.ground_half},
        }));
        prepared.push((cam, meshes));
    }
    let scenes_json = artifacts.join("scenes.json");
    std::fs::write(
        &scenes_json,
        serde_json::to_string_pretty(&json!({ "scenes": json_scenes })).unwrap(),
    )
    .unwrap();
    let t_render = Instant::now();
    if let Err(e) = render(&scenes_json, &artifacts, &tmp.path().join("render.log")) {
        panic!("{e}");
    }
    let render_time = t_render.elapsed();
    let results: serde_json::Value =
        serde_json::from_slice(&std::fs::read(artifacts.join("results.json")).unwrap()).unwrap();

    let mut failures = Vec::new();
    let mut summary = Vec::new();
    let (mut total_px, mut total_band, mut total_records) = (0, 0, 0);
    let (mut total_faces, mut total_corners) = (0, 0);
    for (i, (s, (cam, meshes))) in scenes.iter().zip(&prepared).enumerate() {
        let info = &results["scenes"][i];
        assert_eq!(info["name"], s.name);
        assert!(info["maxVertexAttribs"].as_u64().unwrap() >= 8);
        assert_eq!(info["stencilBits"], 8, "{}: stencil bits", s.name);
        assert_eq!(info["glError"], 0, "{}: GL error after rendering", s.name);
        let rgba = std::fs::read(artifacts.join(format!("{}.rgba", s.name))).unwrap();
        let mult: Vec<i8> = std::fs::read(artifacts.join(format!("{}.mult", s.name)))
            .unwrap()
            .into_iter()
            .map(|b| b as i8)
            .collect();

        let mut truth = predict(meshes, cam);
        mark_volume_corners(&mut truth, meshes, cam);
        let surfaces = Surfaces::new(meshes);
        let c = compare(&truth, &surfaces, &rgba);
        let (records, bad) = compare_multiplicities(meshes, &mult);
        // Surfaces through the light are a separate, documented exclusion;
        // the boundary band is measured against the rest.
        let boundary = c.band - c.on_volume_faces - c.at_corners;
        let fraction = boundary as f64 / (boundary + c.compared).max(1) as f64;
        eprintln!(
            "{:30} {:>6} px compared ({:>5} in shadow), {:>5} in band ({:4.1}%), {:>5} on faces through the light, {:>3} at silhouette vertices, {} mismatches; {:>4} records, {} multiplicity mismatches",
            s.name,
            c.compared,
            c.shadowed,
            boundary,
            100.0 * fraction,
            c.on_volume_faces,
            c.at_corners,
            c.mismatches,
            records,
            bad.len()
        );
        summary.push(json!({
            "scene": s.name, "compared": c.compared, "shadowed": c.shadowed, "band": boundary,
            "on_volume_faces": c.on_volume_faces, "at_silhouette_vertices": c.at_corners, "mismatches": c.mismatches, "records": records,
            "multiplicity_mismatches": bad.len(),
        }));
        total_px += c.compared;
        total_band += boundary;
        total_faces += c.on_volume_faces;
        total_corners += c.at_corners;
        total_records += records;
        if c.mismatches > 0 {
            failures.push(format!(
                "{}: {} pixel mismatches, e.g. {:?}",
                s.name, c.mismatches, c.examples
            ));
        }
        if fraction > MAX_BAND_FRACTION {
            failures.push(format!(
                "{}: {:.1}% of the pixels are in the boundary band (limit {:.0}%)",
                s.name,
                100.0 * fraction,
                100.0 * MAX_BAND_FRACTION
            ));
        }
        if c.shadowed == 0 {
            failures.push(format!("{}: no compared pixel is in shadow", s.name));
        }
        if !bad.is_empty() {
            failures.push(format!("{}: {:?}", s.name, &bad[..bad.len().min(5)]));
        }

        // The comparators must notice a single wrong pixel or record.
        if i == 0 {
            let y = (0..WIDTH * HEIGHT)
                .find(|&p| truth[p].kind != 0 && !in_band(&truth, &surfaces, p))
                .expect("a compared pixel");
            let mut broken = rgba.clone();
            broken[4 * y + 1] ^= 255;
            broken[4 * y + 2] ^= 1;
            assert_eq!(
                compare(&truth, &surfaces, &broken).mismatches,
                c.mismatches + 1,
                "the pixel comparator misses a corrupted pixel"
            );
            let mut broken = mult.clone();
            broken[records / 2] = -broken[records / 2] + 1;
            assert_eq!(
                compare_multiplicities(meshes, &broken).1.len(),
                bad.len() + 1,
                "the multiplicity comparator misses a corrupted record"
            );
        }
    }
    std::fs::write(
        artifacts.join("comparison.json"),
        serde_json::to_string_pretty(&summary).unwrap(),
    )
    .unwrap();
    eprintln!(
        "browser test: {} scenes, {total_px} pixels compared, {total_band} in the boundary band, {total_faces} on faces through the light, {total_corners} at silhouette vertices, {total_records} records; render {:.1} s, total {:.1} s; images in {}",
        scenes.len(),
        render_time.as_secs_f64(),
        start.elapsed().as_secs_f64(),
        artifacts.display()
    );
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// True when pixel `p` is within [`BAND`] pixels of (or is) a pixel that is
/// ambiguous, lies on a face through the light, or does not continue `p`'s
/// surface and shadow count.
fn in_band(truth: &[Truth], surfaces: &Surfaces, p: usize) -> bool {
    band_test(truth, surfaces, p, true)
}

/// [`in_band`] ignoring silhouette vertices (to attribute excluded pixels).
fn in_band_without_corners(truth: &[Truth], surfaces: &Surfaces, p: usize) -> bool {
    band_test(truth, surfaces, p, false)
}

fn band_test(truth: &[Truth], surfaces: &Surfaces, p: usize, corners: bool) -> bool {
    let (x, y) = (p % WIDTH, p / WIDTH);
    let t = truth[p];
    (y.saturating_sub(BAND)..(y + BAND + 1).min(HEIGHT)).any(|ny| {
        (x.saturating_sub(BAND)..(x + BAND + 1).min(WIDTH)).any(|nx| {
            let n = truth[ny * WIDTH + nx];
            n.ambiguous || n.on_volume_face || (corners && n.corner) || !surfaces.continuous(&t, &n)
        })
    })
}

/// The JavaScript loader (web/svpack.js) against the spec's test vector and
/// corrupted variants of it (web/test/loader.test.mjs). Needs only node.
#[test]
fn js_loader_reads_the_spec_test_vector() {
    if Command::new("node").arg("--version").output().is_err() {
        if std::env::var("SVPACK_REQUIRE_BROWSER").is_ok_and(|v| v == "1") {
            panic!("SVPACK_REQUIRE_BROWSER=1 but node is not installed");
        }
        eprintln!("skipping the JavaScript loader test: node is not installed");
        return;
    }
    let out = Command::new("node")
        .arg("--test")
        .arg(common::root().join("web/test/loader.test.mjs"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "web/test/loader.test.mjs failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
