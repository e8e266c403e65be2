//! OBJ loader (placeholder, being written).
use super::Soup;
use crate::error::Result;
use std::path::Path;

/// Loads a `.obj` whose bytes are `data`.
pub fn load_obj(path: &Path, data: Vec<u8>) -> Result<Soup> {
    let _ = data;
    Err(crate::error::Error::input(path, "OBJ loading not implemented yet"))
}
