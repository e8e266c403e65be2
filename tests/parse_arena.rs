//! The OBJ parser's arena (`alloc::arena`) under the allocator the CLI
//! installs: a load hands the arena's chunks over once the models are
//! freed (so the weld can reuse them), a later load in the same process
//! gets an arena too, and the soup is the same as a load without one.

use std::fmt::Write as _;
use svpack::alloc::{HugePageAlloc, KeepFreed, arena};

#[global_allocator]
static GLOBAL: HugePageAlloc = HugePageAlloc;

/// `objects` objects, each a grid of `n` × `n` quads written as triangles,
/// side by side along x.
fn grids(objects: usize, n: usize) -> String {
    let mut s = String::new();
    let mut base = 1;
    for o in 0..objects {
        writeln!(s, "o grid_{o}").unwrap();
        for j in 0..=n {
            for i in 0..=n {
                writeln!(s, "v {} {} {}", o * (n + 2) + i, j, (i * j) % 7).unwrap();
            }
        }
        for j in 0..n {
            for i in 0..n {
                let a = base + j * (n + 1) + i;
                let (b, c, d) = (a + 1, a + n + 1, a + n + 2);
                writeln!(s, "f {a} {b} {d}\nf {a} {d} {c}").unwrap();
            }
        }
        base += (n + 1) * (n + 1);
    }
    s
}

/// Caught (by hand): the streaming parse run outside the scope (0 bytes
/// handed over), and the loader without its warm-up of tobj (the second
/// load's arena: tobj's hash seeds, made in the first, held its chunk). The
/// arena dropped before the soup is built is no break: its chunks go as the
/// models are freed.
#[test]
fn an_obj_load_hands_its_arena_over_and_gives_the_same_soup() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("grids.obj");
    std::fs::write(&path, grids(200, 30)).unwrap();
    let _keep = KeepFreed::new();

    let before = arena::handed_over();
    let with = svpack::load::load(&path).unwrap();
    let handed = arena::handed_over() - before;
    // tobj's models alone are about 6.5 MB here.
    assert!(
        handed >= 2 * arena::CHUNK,
        "{handed} bytes handed over by the load"
    );

    // A second load gets an arena too: the first left no chunk held.
    let before = arena::handed_over();
    let again = svpack::load::load(&path).unwrap();
    assert!(
        arena::handed_over() - before >= 2 * arena::CHUNK,
        "the second load's arena handed over"
    );
    assert!(again.indices == with.indices);

    // An arena held here leaves the load none: malloc's blocks.
    let held = arena::open(1 << 20);
    let before = arena::handed_over();
    let without = svpack::load::load(&path).unwrap();
    assert_eq!(arena::handed_over(), before, "no arena for the second load");
    drop(held);

    assert_eq!(with.positions.len(), without.positions.len());
    assert!(with.positions == without.positions);
    assert!(with.indices == without.indices);
    assert_eq!(with.parts.len(), 200);
    for (a, b) in with.parts.iter().zip(&without.parts) {
        assert_eq!(
            (&a.name, a.first_triangle, a.triangle_count),
            (&b.name, b.first_triangle, b.triangle_count)
        );
    }
}
