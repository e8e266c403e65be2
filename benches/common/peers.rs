//! The parsers our loaders sit on, called alone, as the peers of
//! `svpack::load::load` in the stages and load-overhead benchmarks: what a
//! loader that only wanted positions and indices would have to run anyway.

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
