//! Prints per-stage wall times for one input (a quick profile, not a benchmark).
use std::time::Instant;
fn main() {
    let p = std::path::PathBuf::from(std::env::args().nth(1).expect("input"));
    let t = Instant::now();
    let soup = svpack::load::load(&p).unwrap();
    let t_load = t.elapsed();
    let t = Instant::now();
    let w = svpack::weld::weld(&soup.positions, &soup.indices);
    let t_weld = t.elapsed();
    let t = Instant::now();
    let e = svpack::topology::build_edges(&w.triangles, w.positions.len());
    let t_topo = t.elapsed();
    let t = Instant::now();
    let l = svpack::layout::layout(&w, &e, 5);
    let t_layout = t.elapsed();
    println!(
        "load {t_load:?} weld {t_weld:?} topology {t_topo:?} layout {t_layout:?} ({} tris, {} bytes)",
        w.triangle_count(),
        l.sides_bytes() + l.caps_bytes()
    );
}
