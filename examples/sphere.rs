//! Writes a latitude/longitude sphere as OBJ, for scale measurements:
//! `cargo run --release --example sphere -- 708 sphere.obj` gives 1,002,528
//! triangles (1,001,112 after the degenerate ones at the poles are dropped).

use std::fmt::Write;

/// OBJ text of a sphere with `n` latitude bands and `n` longitude segments.
pub fn sphere_obj(n: usize) -> String {
    let mut s = String::new();
    for j in 0..=n {
        let th = std::f64::consts::PI * j as f64 / n as f64;
        for i in 0..n {
            let ph = std::f64::consts::TAU * i as f64 / n as f64;
            let _ = writeln!(
                s,
                "v {:.7} {:.7} {:.7}",
                th.sin() * ph.cos(),
                th.cos(),
                th.sin() * ph.sin()
            );
        }
    }
    let id = |i: usize, j: usize| j * n + (i % n) + 1;
    for j in 0..n {
        for i in 0..n {
            let _ = writeln!(
                s,
                "f {} {} {}\nf {} {} {}",
                id(i, j),
                id(i + 1, j + 1),
                id(i, j + 1),
                id(i, j),
                id(i + 1, j),
                id(i + 1, j + 1)
            );
        }
    }
    s
}

#[allow(dead_code)]
fn main() {
    let mut args = std::env::args().skip(1);
    let n: usize = args.next().and_then(|a| a.parse().ok()).unwrap_or(708);
    let out = args.next().unwrap_or_else(|| "sphere.obj".into());
    std::fs::write(&out, sphere_obj(n)).expect("write");
    eprintln!("wrote {out}: {} triangles", 2 * n * n);
}
