//! The parsers our loaders sit on, called alone, as the peers of
//! `svpack::load::load` in the stages and load-overhead benchmarks: what a
//! loader that only wanted positions and indices would have to run anyway;
//! the standard library's sort as the peer of the weld's; and
//! meshoptimizer's adjacency with the part of our build it is measured
//! against (`ours_buckets`), for the stages bench and `stage_probe`.

use std::path::Path;

/// File read + `tobj::load_obj_buf` with the options our OBJ loader uses
/// (untriangulated, one index per attribute, no material files). Returns the
/// number of position floats, so the work cannot be optimised away.
pub fn tobj_load(path: &Path) -> usize {
    let text = std::fs::read(path).unwrap();
    let options = tobj::LoadOptions {
        single_index: false,
        triangulate: false,
        ignore_points: false,
        ignore_lines: false,
    };
    let mut reader = text.as_slice();
    let (models, _) =
        tobj::load_obj_buf(&mut reader, &options, |_| Ok(Default::default())).unwrap();
    models.iter().map(|m| m.mesh.positions.len()).sum()
}

/// File read, `gltf::Gltf::from_slice`, buffers (the GLB blob or files beside
/// the input), and the crate's readers for the positions and indices of every
/// primitive. Returns the counts.
pub fn gltf_crate_load(path: &Path) -> (usize, usize) {
    let bytes = std::fs::read(path).unwrap();
    let doc = gltf::Gltf::from_slice(&bytes).unwrap();
    let buffers: Vec<Vec<u8>> = doc
        .buffers()
        .map(|b| match b.source() {
            gltf::buffer::Source::Bin => doc.blob.clone().unwrap(),
            gltf::buffer::Source::Uri(uri) => {
                std::fs::read(path.parent().unwrap().join(uri)).unwrap()
            }
        })
        .collect();
    let (mut positions, mut indices) = (0, 0);
    for mesh in doc.meshes() {
        for prim in mesh.primitives() {
            let r = prim.reader(|b| Some(&buffers[b.index()]));
            let p: Vec<[f32; 3]> = r.read_positions().unwrap().collect();
            let i: Vec<u32> = match r.read_indices() {
                Some(i) => i.into_u32().collect(),
                None => (0..p.len() as u32).collect(),
            };
            positions += p.len();
            indices += i.len();
        }
    }
    (positions, indices)
}

/// The peer of `weld::weld` (the stages bench's `weld` group and
/// `stage_probe -- weld`): the sort at the weld's heart done by the
/// standard library. One 128-bit word per vertex, the order keys of its
/// x, y and z above its index (as the weld makes them: `-0.0` as `+0.0`,
/// then the sign bit flipped for positives and every bit for negatives),
/// sorted by `sort_unstable`, and nothing else: no numbering, no
/// triangles. Why: `weld` sorts with code of its own (a bucket sort on x,
/// then counting passes and insertion sorts per bucket), and this says
/// what the best general sort at hand costs for the sort alone.
pub fn sorted_vertex_words(positions: &[[f32; 3]]) -> Vec<u128> {
    let mut words: Vec<u128> = positions
        .iter()
        .enumerate()
        .map(|(i, p)| position_key(p) << 32 | i as u128)
        .collect();
    words.sort_unstable();
    words
}

/// The 96-bit sort key of a position in [`sorted_vertex_words`].
fn position_key(p: &[f32; 3]) -> u128 {
    let key = |v: f32| {
        let b = (if v == 0.0 { 0.0 } else { v }).to_bits();
        u128::from(b ^ (((b as i32 >> 31) as u32) | 0x8000_0000))
    };
    key(p[0]) << 64 | key(p[1]) << 32 | key(p[2])
}

/// Whether the peer did the weld's work: `welded` (a weld's positions, in
/// its order) is a subsequence of the distinct keys of `sorted` (the
/// weld drops positions no kept triangle uses). Checked where the stages
/// bench prepares each mesh.
pub fn welded_in_sorted_words(sorted: &[u128], welded: &[[f32; 3]]) -> bool {
    let mut next = welded.iter().map(position_key).peekable();
    let mut last = None;
    for key in sorted.iter().map(|w| w >> 32) {
        if last == Some(key) {
            continue;
        }
        last = Some(key);
        if next.peek() == Some(&key) {
            next.next();
        }
    }
    next.next().is_none()
}

/// meshoptimizer's adjacency index buffer from an unwelded soup (it matches
/// positions itself): the topology peer of the stages bench.
pub fn meshopt_adjacency(positions: &[[f32; 3]], indices: &[u32]) -> Vec<u32> {
    let adapter = meshopt::VertexDataAdapter::new(
        meshopt::typed_to_bytes(positions),
        std::mem::size_of::<[f32; 3]>(),
        0,
    )
    .unwrap();
    meshopt::generate_adjacency_indices(indices, &adapter)
}

/// What an uncompressed build does before its write stage (which fills the
/// records straight into the file): weld, topology, the bucket counts and
/// the edge statistics, which the build takes from the plan's histogram
/// (`Plan::edge_stats`; until the twenty-seventh round the stages bench also
/// ran `topology::edge_stats`, a pass over the edges the build has not
/// made since the fourteenth round). As a one-thread build does since the
/// forty-fifth round, the topology takes the welded triangles and frees
/// them once listed (`topology::build_edges_opposites_only_owned`), so the
/// welded mesh returned has no triangles.
pub fn ours_buckets(
    soup: &svpack::load::Soup,
) -> (
    svpack::weld::Welded,
    svpack::topology::Edges,
    svpack::topology::EdgeStats,
    svpack::layout::Plan,
) {
    let mut w = svpack::weld::weld_without_sources(&soup.positions, &soup.indices);
    let triangles = w.triangle_count();
    let e = svpack::topology::build_edges_opposites_only_owned(
        std::mem::take(&mut w.triangles),
        w.positions.len(),
    );
    let plan = svpack::layout::Plan::new(&e, triangles, svpack::layout::DEFAULT_MAX_MULT);
    let stats = plan.edge_stats();
    (w, e, stats, plan)
}
