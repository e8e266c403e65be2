//! glTF 2.0 loader (placeholder, being written).
use super::Soup;
use crate::error::Result;
use std::path::Path;

/// Loads a `.gltf` or `.glb` whose bytes are `data`.
pub fn load_gltf(path: &Path, data: Vec<u8>) -> Result<Soup> {
    let _ = data;
    Err(crate::error::Error::input(path, "glTF loading not implemented yet"))
}
