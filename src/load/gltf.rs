//! glTF 2.0 loader for `.gltf` (JSON with external or `data:` buffers) and
//! `.glb` (binary container) files.
//!
//! The `gltf` crate is used only for its JSON data model (`gltf::json`) and its
//! validation pass. Everything that touches buffer bytes is done here rather
//! than through `gltf::import`/`Reader` because
//! * the crate has no `KHR_mesh_quantization` support (integer positions),
//! * its GLB parser can underflow on a corrupt header, and its readers do not
//!   report *why* an accessor is unreadable, while we want every structural
//!   problem reported as an [`Error::Input`] naming the file, the
//!   mesh/primitive/accessor and the numbers involved.
//!
//! Positions are decoded and transformed in f64 and rounded to f32 exactly
//! once, so a vertex deep in a node hierarchy with large translations does not
//! pick up rounding error at every level.

use super::{InputDigest, Part, PendingDigest, Soup};
use crate::error::{Error, Result};
use crate::file_bytes::FileBytes;
use base64::Engine as _;
use gltf::json;
use json::accessor::{ComponentType, Type};
use json::mesh::{Mode, Semantic};
use json::validation::{Checked, Validate as _};
use std::collections::BTreeSet;
use std::path::Path;

/// Upper bound on node visits while expanding the scene graph. A valid glTF
/// node graph is a forest, so this is only reached by a graph in which nodes
/// are shared by several parents, which could otherwise expand exponentially.
const MAX_NODE_VISITS: usize = 1 << 24;

/// Upper bound on the element count of an accessor without a `bufferView`
/// (all zeros plus sparse overrides). Such an accessor is backed by no bytes,
/// so nothing else bounds the memory a hostile count would make us allocate.
const MAX_UNBACKED_COUNT: u64 = 1 << 26;

/// How many validation problems an error message lists before "and N more".
const MAX_LISTED_PROBLEMS: usize = 3;

/// Loads a `.gltf` or `.glb` whose bytes are `data` (read or mapped) into a
/// world-space soup.
///
/// `path` locates external buffers (relative URIs resolve against its
/// directory) and names the file in errors. The default scene is used; without
/// one, every scene in order; without any scene, every mesh once at the origin
/// (with a warning). Each triangle primitive instance (TRIANGLES,
/// TRIANGLE_STRIP, TRIANGLE_FAN; indexed or not) becomes one [`Part`];
/// points and lines are skipped and counted. Positions may be FLOAT or, per
/// `KHR_mesh_quantization`, (normalized) BYTE/UNSIGNED_BYTE/SHORT/
/// UNSIGNED_SHORT, dense and/or sparse. Mirroring node transforms flip the
/// winding so front faces stay front faces.
///
/// Every structural problem (truncated GLB, missing or short buffer, view or
/// accessor out of bounds, index out of range, recursive node graph, wrong
/// accessor type, unsupported version or required geometry extension) is an
/// [`Error::Input`]; NaN/Inf positions are passed through for later stages.
pub fn load_gltf(path: &Path, data: impl Into<FileBytes>) -> Result<Soup> {
    let (mut soup, digest) = load_gltf_deferred(path, data, |_| Ok(()))?;
    (soup.input_bytes, soup.input_sha256) = digest.finish();
    Ok(soup)
}

/// [`load_gltf`], then `check` of the soup (its error is returned instead),
/// leaving the input's digest possibly unfinished: the soup's `input_bytes`
/// and `input_sha256` are zero, and the [`PendingDigest`] gives them.
///
/// Why, in a build with two threads or more: the digest's thread hashes
/// the whole file (textures too, 1.2–2 GB/s) while this one parses and
/// decodes the geometry, which takes less time: on the dragon's GLB, 13 ms
/// of hashing beside 6 ms of decoding. Here `check` runs in that time
/// (`check_soup` after the load was 1.2–1.6 ms more of a two-thread
/// build), then the digest stops where it has got to, the load returns,
/// and the build hashes the rest beside the output's payload, where one
/// thread waits on the other's copying into the page cache. A glTF with
/// external buffers is hashed whole here, as [`load_gltf`] does.
pub fn load_gltf_deferred(
    path: &Path,
    data: impl Into<FileBytes>,
    check: impl FnOnce(&Soup) -> Result<()>,
) -> Result<(Soup, PendingDigest)> {
    let data: FileBytes = data.into();
    // The digest starts on the file's bytes now, beside the parse (see
    // `DigestHead`), and takes the external buffers once they are read.
    let (soup, head) =
        super::with_digest_head(&data, |head| load_gltf_with(path, &data, head, check))?;
    let digest = match head {
        // Bytes left: the build hashes them (and keeps `data` until then).
        Some((digest, from)) if from < data.len() => {
            data.release_prefix(from);
            PendingDigest::Rest { digest, data, from }
        }
        Some((digest, _)) => {
            let (bytes, sha) = digest.finish();
            PendingDigest::Done(bytes, sha)
        }
        None => PendingDigest::Done(soup.input_bytes, soup.input_sha256),
    };
    Ok((soup, digest))
}

/// [`load_gltf_deferred`] of `data`, whose digest `head` has begun: the soup
/// with its digest, or without it and the digest of the file so far with
/// the number of bytes it covers.
fn load_gltf_with(
    path: &Path,
    data: &FileBytes,
    head: super::DigestHead<'_>,
    check: impl FnOnce(&Soup) -> Result<()>,
) -> Result<(Soup, Option<(InputDigest, usize)>)> {
    let mut warnings = Vec::new();

    let container = split_container(path, data, &mut warnings)?;
    check_version(path, container.json)?;
    let root = parse_root(path, container.json)?;
    check_extensions(path, &root, &mut warnings)?;
    let geometry = GeometryRefs::collect(&root, |_| true);
    check_references(path, &root, &geometry)?;
    validate(path, &root, &geometry, &mut warnings)?;

    let instances = collect_instances(path, &root, &mut warnings)?;
    // Only buffers feeding instanced triangle geometry are read: a missing
    // texture-coordinate-only .bin must not stop us.
    let mut used_meshes = vec![false; root.meshes.len()];
    for inst in &instances {
        if let Some(used) = used_meshes.get_mut(inst.mesh) {
            *used = true;
        }
    }
    let needed = GeometryRefs::collect(&root, |m| used_meshes.get(m) == Some(&true)).buffers;
    let mut external = Vec::new();
    let buffers = load_buffers(path, &root, container.bin, &needed, &mut external)?;
    let ctx = Ctx {
        path,
        root: &root,
        buffers,
    };

    // The input's SHA-256 covers the file, then the external buffers it
    // read, in read order. Every byte is in memory now, so the digest is
    // completed beside the decoding when there are threads to spare, or,
    // for a file alone, left to the caller where it has got to (see
    // `DigestHead`).
    let rest: Vec<&[u8]> = external
        .iter()
        .filter_map(|&b| ctx.buffers[b].as_deref())
        .collect();
    let decode = || {
        let mut soup = Soup::default();
        reserve_soup(&ctx, &instances, &mut soup);
        build_soup(&ctx, &instances, &mut soup, &mut warnings)?;
        check(&soup)?;
        Ok(soup)
    };
    let (whole, so_far, built) = if rest.is_empty() {
        let (so_far, built) = head.stop_after(decode);
        (None, Some(so_far), built)
    } else {
        let (whole, built) = head.finish_while(&rest, decode);
        (Some(whole), None, built)
    };
    let mut soup = built?;
    soup.input_vertices = soup.positions.len() as u64;
    if soup.indices.is_empty() {
        warnings.push("no triangles found in the scene".to_string());
    }
    soup.stats.warnings = warnings;
    if let Some((bytes, sha)) = whole {
        (soup.input_bytes, soup.input_sha256) = (bytes, sha);
    }
    Ok((soup, so_far))
}

// ---------------------------------------------------------------------------
// Container (GLB or plain JSON)
// ---------------------------------------------------------------------------

/// The JSON text and, for a GLB, its BIN chunk.
struct Container<'a> {
    json: &'a [u8],
    bin: Option<&'a [u8]>,
}

fn u32_le(b: &[u8], at: usize) -> Option<u32> {
    let s = b.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
}

/// Splits a GLB into JSON and BIN chunks (or passes JSON through), checking
/// every length against the bytes actually present. Our own parser rather than
/// `gltf::Glb`, whose header-length arithmetic can underflow on corrupt input.
fn split_container<'a>(
    path: &Path,
    data: &'a [u8],
    warnings: &mut Vec<String>,
) -> Result<Container<'a>> {
    if !data.starts_with(b"glTF") {
        return Ok(Container {
            json: trim_json(data),
            bin: None,
        });
    }
    let err = |m: String| Error::input(path, m);
    let (Some(version), Some(length)) = (u32_le(data, 4), u32_le(data, 8)) else {
        return Err(err(format!(
            "truncated GLB: the 12-byte header is incomplete (file is {} bytes)",
            data.len()
        )));
    };
    if version != 2 {
        return Err(err(format!(
            "GLB container version {version} is not supported (need 2; version 1 is glTF 1.0)"
        )));
    }
    let length = length as usize;
    if length > data.len() {
        return Err(err(format!(
            "truncated GLB: the header declares {length} bytes but the file has only {}",
            data.len()
        )));
    }
    if length < 12 {
        return Err(err(format!(
            "corrupt GLB: the header declares a total length of {length} bytes"
        )));
    }
    if length < data.len() {
        warnings.push(format!(
            "ignored {} bytes after the end of the GLB container",
            data.len() - length
        ));
    }
    let body = &data[..length];
    let mut pos = 12;
    let mut chunk_no = 0usize;
    let mut json = None;
    let mut bin = None;
    while pos < length {
        let (Some(chunk_len), Some(kind)) = (u32_le(body, pos), body.get(pos + 4..pos + 8)) else {
            return Err(err(format!(
                "truncated GLB: chunk {chunk_no} header at byte {pos} is incomplete"
            )));
        };
        let start = pos + 8;
        let end = start
            .checked_add(chunk_len as usize)
            .filter(|&e| e <= length)
            .ok_or_else(|| {
                err(format!(
                    "truncated GLB: chunk {chunk_no} ({}) at byte {pos} declares {chunk_len} bytes but only {} remain",
                    chunk_kind(kind),
                    length - start
                ))
            })?;
        let payload = &body[start..end];
        match kind {
            b"JSON" if chunk_no == 0 => json = Some(payload),
            b"JSON" => return Err(err("corrupt GLB: more than one JSON chunk".to_string())),
            _ if chunk_no == 0 => {
                return Err(err(format!(
                    "corrupt GLB: the first chunk must be JSON, found {}",
                    chunk_kind(kind)
                )));
            }
            b"BIN\0" if bin.is_none() => bin = Some(payload),
            b"BIN\0" => warnings.push("ignored a second GLB BIN chunk".to_string()),
            // The spec says loaders must ignore chunks of unknown type.
            _ => {}
        }
        pos = end;
        chunk_no += 1;
    }
    let json = json.ok_or_else(|| err("corrupt GLB: no JSON chunk".to_string()))?;
    Ok(Container {
        json: trim_json(json),
        bin,
    })
}

fn chunk_kind(kind: &[u8]) -> String {
    format!("{:?}", String::from_utf8_lossy(kind))
}

/// Drops a UTF-8 BOM and trailing NUL/space padding, which some exporters
/// write although the spec forbids the former and wants spaces for the latter.
fn trim_json(json: &[u8]) -> &[u8] {
    let json = json.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(json);
    let end = json
        .iter()
        .rposition(|&b| !matches!(b, 0 | b' ' | b'\t' | b'\r' | b'\n'))
        .map_or(0, |i| i + 1);
    &json[..end]
}

/// JSON texts longer than this are not read for [`soup_bytes`]: such a
/// file holds its buffers in `data:` URIs, so its size already counts them.
const ESTIMATE_JSON_MAX: u64 = 16 << 20;

/// The length of a glTF's JSON plus the bytes of the soup its load will
/// make, from `file` whose first bytes are `head` and whose length is
/// `size`: for every mesh instance the loader places (`collect_instances`:
/// the default scene, or every scene, or every mesh once), each triangle
/// primitive's positions and triangles, 12 bytes each. Only the JSON is
/// read, never a buffer. None when the JSON cannot be read or parsed, is
/// longer than 16 MiB, or its node graph is one the load refuses.
///
/// What a batch orders its inputs by and budgets their memory with
/// (`load::soup_estimate`). Why instances and not the accessors: a mesh
/// that three nodes place is welded three times, and a primitive's normals,
/// texture coordinates and points are never read (2CylinderEngine's 67
/// instances of 29 meshes make a 2.36 MiB soup from 1.8 MiB of accessors).
pub fn soup_bytes(file: &mut std::fs::File, head: &[u8], size: u64) -> Option<u64> {
    use std::io::{Read, Seek, SeekFrom};
    let (start, len) = if head.starts_with(b"glTF") {
        // A GLB: its first chunk is the JSON (12-byte header, then the
        // chunk's length and type).
        if head.get(16..20) != Some(b"JSON") {
            return None;
        }
        (20, u64::from(u32_le(head, 12)?))
    } else {
        (0, size)
    };
    if len > ESTIMATE_JSON_MAX {
        return None;
    }
    file.seek(SeekFrom::Start(start)).ok()?;
    let mut json = Vec::with_capacity(len as usize);
    file.take(len).read_to_end(&mut json).ok()?;
    let nowhere = Path::new("");
    let root = parse_root(nowhere, trim_json(&json)).ok()?;
    let instances = collect_instances(nowhere, &root, &mut Vec::new()).ok()?;
    let count = |a: usize| root.accessors.get(a).map_or(0, |acc| acc.count.0);
    let mut soup = 0u64;
    for instance in &instances {
        let Some(mesh) = root.meshes.get(instance.mesh) else {
            continue;
        };
        for prim in &mesh.primitives {
            // An invalid mode is refused by the load; count it as triangles.
            let mode = match prim.mode {
                Checked::Valid(mode) => mode,
                Checked::Invalid => Mode::Triangles,
            };
            let positions = position_accessor(prim).map_or(0, count);
            let corners = prim.indices.map_or(positions, |a| count(a.value()));
            let triangles = triangle_count(mode, corners as usize) as u64;
            if triangles > 0 {
                soup = soup.saturating_add((positions + triangles).saturating_mul(12));
            }
        }
    }
    Some(soup.saturating_add(json.len() as u64))
}

// ---------------------------------------------------------------------------
// Version and extensions
// ---------------------------------------------------------------------------

#[derive(serde::Deserialize)]
struct VersionProbe {
    asset: Option<AssetProbe>,
}

#[derive(serde::Deserialize)]
struct AssetProbe {
    version: Option<serde_json::Value>,
    #[serde(rename = "minVersion")]
    min_version: Option<serde_json::Value>,
}

/// Checks `asset.version` before the full parse: a glTF 1.0 file does not fit
/// the 2.0 data model, and "version 1.0 is not supported" is a far better
/// message than the serde error the full parse would give.
fn check_version(path: &Path, json: &[u8]) -> Result<()> {
    // If even the probe fails, the full parse reports the JSON problem.
    let Ok(probe) = serde_json::from_slice::<VersionProbe>(json) else {
        return Ok(());
    };
    let err = |m: String| Err(Error::input(path, m));
    let Some(asset) = probe.asset else {
        return err("no \"asset\" object, so this is not a glTF 2.x file".to_string());
    };
    match asset.version {
        None => return err("asset.version is missing (need \"2.x\")".to_string()),
        Some(serde_json::Value::String(v)) if !v.starts_with("2.") => {
            return err(format!("glTF version {v} is not supported (need 2.x)"));
        }
        Some(serde_json::Value::String(_)) => {}
        Some(other) => {
            return err(format!(
                "asset.version must be a string such as \"2.0\", found {other}"
            ));
        }
    }
    if let Some(serde_json::Value::String(min)) = asset.min_version {
        let mut parts = min.split('.');
        let major = parts.next().and_then(|p| p.parse::<u32>().ok());
        let minor = parts.next().and_then(|p| p.parse::<u32>().ok());
        if major != Some(2) || minor.is_none_or(|m| m > 0) {
            return err(format!(
                "the file needs glTF {min} (asset.minVersion); svpack reads glTF 2.0"
            ));
        }
    }
    Ok(())
}

/// Deserializes the glTF JSON. gltf-json 1.4 requires `scene.nodes`, which
/// the glTF schema makes optional (an empty scene is valid), so when the typed
/// parse fails we retry once with missing `nodes` filled in. The retry only
/// runs on failure, so valid files are parsed once.
fn parse_root(path: &Path, json_text: &[u8]) -> Result<json::Root> {
    let first_err = match serde_json::from_slice::<json::Root>(json_text) {
        Ok(root) => return Ok(root),
        Err(e) => e,
    };
    let err = || Error::input(path, format!("invalid glTF JSON: {first_err}"));
    let Ok(mut value) = serde_json::from_slice::<serde_json::Value>(json_text) else {
        return Err(err());
    };
    let mut patched = false;
    if let Some(scenes) = value.get_mut("scenes").and_then(|s| s.as_array_mut()) {
        for scene in scenes.iter_mut().filter_map(|s| s.as_object_mut()) {
            if !scene.contains_key("nodes") {
                scene.insert("nodes".to_string(), serde_json::Value::Array(Vec::new()));
                patched = true;
            }
        }
    }
    if !patched {
        return Err(err());
    }
    serde_json::from_value(value).map_err(|_| err())
}

/// What an extension means for geometry loading.
#[derive(Debug, PartialEq)]
enum ExtensionKind {
    /// Decoded by this loader.
    Handled,
    /// Only affects appearance, metadata or animation: safe to ignore.
    NoGeometry,
    /// May change geometry and we cannot decode it.
    Geometry,
}

fn classify_extension(name: &str) -> ExtensionKind {
    const HANDLED: &[&str] = &["KHR_mesh_quantization"];
    const NO_GEOMETRY: &[&str] = &[
        "KHR_xmp_json_ld",
        "KHR_xmp",
        "KHR_animation_pointer",
        "KHR_techniques_webgl",
        "KHR_lights_punctual",
        "EXT_lights_image_based",
    ];
    // Vendor prefixes vary (KHR_, EXT_, MSFT_, ADOBE_, ...); what follows says
    // what the extension is about.
    const NO_GEOMETRY_TOPICS: &[&str] = &[
        "materials_",
        "material_",
        "texture_",
        "textures_",
        "lights_",
        "light_",
        "techniques_",
        "packing_",
    ];
    if HANDLED.contains(&name) {
        return ExtensionKind::Handled;
    }
    if NO_GEOMETRY.contains(&name) {
        return ExtensionKind::NoGeometry;
    }
    let topic = name.split_once('_').map_or("", |(_, rest)| rest);
    if NO_GEOMETRY_TOPICS.iter().any(|t| topic.starts_with(t)) {
        ExtensionKind::NoGeometry
    } else {
        ExtensionKind::Geometry
    }
}

/// Rejects required extensions that change geometry we cannot decode, and
/// warns about used-but-optional ones whose fallback may differ.
fn check_extensions(path: &Path, root: &json::Root, warnings: &mut Vec<String>) -> Result<()> {
    for ext in &root.extensions_required {
        if classify_extension(ext) != ExtensionKind::Geometry {
            continue;
        }
        let msg = match ext.as_str() {
            "KHR_draco_mesh_compression" => format!(
                "the file requires extension {ext} (Draco-compressed meshes), which svpack cannot decode; export it without Draco compression"
            ),
            "EXT_meshopt_compression" | "KHR_meshopt_compression" => format!(
                "the file requires extension {ext} (meshoptimizer-compressed buffers), which svpack cannot decode; export it without meshopt compression"
            ),
            _ => format!(
                "the file requires extension {ext}, which svpack does not support (it may change geometry)"
            ),
        };
        return Err(Error::input(path, msg));
    }
    if root
        .extensions_used
        .iter()
        .any(|e| e == "EXT_mesh_gpu_instancing")
    {
        warnings.push(
            "EXT_mesh_gpu_instancing is not supported; each instanced node's mesh is loaded once at the node's transform".to_string(),
        );
    }
    Ok(())
}

// ---------------------------------------------------------------------------
// Reference checks and validation
// ---------------------------------------------------------------------------

/// Accessors, buffer views and buffers that feed triangle geometry (POSITION
/// and indices of triangle primitives). Problems in these are fatal; problems
/// elsewhere (texture coordinates, animation data) cannot affect our output.
#[derive(Default)]
struct GeometryRefs {
    accessors: BTreeSet<usize>,
    views: BTreeSet<usize>,
    buffers: BTreeSet<usize>,
}

impl GeometryRefs {
    fn collect(root: &json::Root, include_mesh: impl Fn(usize) -> bool) -> Self {
        let mut refs = GeometryRefs::default();
        for (mi, mesh) in root.meshes.iter().enumerate() {
            if !include_mesh(mi) {
                continue;
            }
            for prim in &mesh.primitives {
                if !matches!(
                    prim.mode,
                    Checked::Invalid
                        | Checked::Valid(Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan)
                ) {
                    continue;
                }
                if let Some(a) = position_accessor(prim) {
                    refs.accessors.insert(a);
                }
                if let Some(a) = prim.indices {
                    refs.accessors.insert(a.value());
                }
            }
        }
        for &a in &refs.accessors {
            let Some(acc) = root.accessors.get(a) else {
                continue;
            };
            if let Some(v) = acc.buffer_view {
                refs.views.insert(v.value());
            }
            if let Some(s) = &acc.sparse {
                refs.views.insert(s.indices.buffer_view.value());
                refs.views.insert(s.values.buffer_view.value());
            }
        }
        for &v in &refs.views {
            if let Some(view) = root.buffer_views.get(v) {
                refs.buffers.insert(view.buffer.value());
            }
        }
        refs
    }
}

fn position_accessor(prim: &json::mesh::Primitive) -> Option<usize> {
    prim.attributes
        .get(&Checked::Valid(Semantic::Positions))
        .map(|a| a.value())
}

/// Checks the index references that geometry depends on, with messages that
/// say which object refers to what. Runs before gltf-json validation, whose
/// primitive hook indexes the POSITION accessor without a bounds check.
fn check_references(path: &Path, root: &json::Root, geo: &GeometryRefs) -> Result<()> {
    let err = |m: String| Err(Error::input(path, m));
    let (n_scenes, n_nodes, n_meshes) = (root.scenes.len(), root.nodes.len(), root.meshes.len());
    let (n_acc, n_views, n_bufs) = (
        root.accessors.len(),
        root.buffer_views.len(),
        root.buffers.len(),
    );
    if let Some(s) = root.scene
        && s.value() >= n_scenes
    {
        return err(format!(
            "default scene {s} does not exist (the file has {n_scenes} scenes)"
        ));
    }
    for (si, scene) in root.scenes.iter().enumerate() {
        if let Some(n) = scene.nodes.iter().find(|n| n.value() >= n_nodes) {
            return err(format!(
                "scene {si} lists node {n}, but the file has {n_nodes} nodes"
            ));
        }
    }
    for (ni, node) in root.nodes.iter().enumerate() {
        if let Some(c) = node
            .children
            .iter()
            .flatten()
            .find(|c| c.value() >= n_nodes)
        {
            return err(format!(
                "node {ni} has child node {c}, but the file has {n_nodes} nodes"
            ));
        }
        if let Some(m) = node.mesh.filter(|m| m.value() >= n_meshes) {
            return err(format!(
                "node {ni} refers to mesh {m}, but the file has {n_meshes} meshes"
            ));
        }
    }
    for (mi, mesh) in root.meshes.iter().enumerate() {
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            let what = || primitive_desc(root, mi, pi);
            match position_accessor(prim) {
                None => return err(format!("{} has no POSITION attribute", what())),
                Some(a) if a >= n_acc => {
                    return err(format!(
                        "{}: POSITION refers to accessor {a}, but the file has {n_acc} accessors",
                        what()
                    ));
                }
                Some(_) => {}
            }
            if let Some(a) = prim.indices.filter(|a| a.value() >= n_acc) {
                return err(format!(
                    "{}: indices refer to accessor {a}, but the file has {n_acc} accessors",
                    what()
                ));
            }
        }
    }
    for &a in &geo.accessors {
        let Some(acc) = root.accessors.get(a) else {
            continue;
        };
        let views = acc.buffer_view.iter().map(|v| ("bufferView", v.value()));
        let sparse = acc.sparse.iter().flat_map(|s| {
            [
                ("sparse.indices.bufferView", s.indices.buffer_view.value()),
                ("sparse.values.bufferView", s.values.buffer_view.value()),
            ]
        });
        if let Some((field, v)) = views.chain(sparse).find(|(_, v)| *v >= n_views) {
            return err(format!(
                "accessor {a}: {field} {v} does not exist (the file has {n_views} bufferViews)"
            ));
        }
    }
    for &v in &geo.views {
        if let Some(view) = root.buffer_views.get(v) {
            let b = view.buffer.value();
            if b >= n_bufs {
                return err(format!(
                    "bufferView {v} refers to buffer {b}, but the file has {n_bufs} buffers"
                ));
            }
        }
    }
    Ok(())
}

/// What to do with one gltf-json validation problem.
#[derive(Debug, PartialEq)]
enum Severity {
    /// Irrelevant or handled by our own checks.
    Ignore,
    /// Outside the geometry: reported as a warning.
    Warn,
    /// Affects geometry: the file is rejected.
    Fatal,
}

/// Splits a validation path like `meshes[2].primitives[0].mode` into
/// (`meshes`, Some(2), `.primitives[0].mode`).
fn split_path(p: &str) -> (&str, Option<usize>, &str) {
    let head_end = p.find(['[', '.', ' ']).unwrap_or(p.len());
    let (head, rest) = p.split_at(head_end);
    if let Some(after) = rest.strip_prefix('[')
        && let Some(close) = after.find(']')
        && let Ok(i) = after[..close].parse()
    {
        return (head, Some(i), &after[close + 1..]);
    }
    (head, None, rest)
}

fn classify_problem(path: &str, geo: &GeometryRefs) -> Severity {
    let (head, index, rest) = split_path(path);
    let in_set = |set: &BTreeSet<usize>| index.is_some_and(|i| set.contains(&i));
    let fatal_if = |cond: bool| {
        if cond {
            Severity::Fatal
        } else {
            Severity::Warn
        }
    };
    match head {
        // Checked by `check_extensions` with our own notion of "supported".
        "extensionsRequired" => Severity::Ignore,
        "asset" | "scene" | "scenes" => Severity::Fatal,
        "nodes" => fatal_if(
            ![".camera", ".skin", ".weights", ".extensions"]
                .iter()
                .any(|f| rest.starts_with(f)),
        ),
        "meshes" => {
            if let Some(attr) = rest.split_once(".attributes[").map(|(_, a)| a) {
                // Only POSITION is read; its min/max are not needed (and
                // quantized files may state them in integer units). Other
                // attributes, including custom `_FOO` ones that gltf-json
                // calls invalid without its `extras` feature, are never read.
                if attr.starts_with("\"POSITION\"]")
                    && !rest.ends_with(".min")
                    && !rest.ends_with(".max")
                {
                    Severity::Fatal
                } else {
                    Severity::Ignore
                }
            } else {
                fatal_if(
                    ![".material", ".targets", ".weights", ".extensions"]
                        .iter()
                        .any(|f| rest.contains(f)),
                )
            }
        }
        "accessors" => fatal_if(in_set(&geo.accessors)),
        // Strides are checked against the accessor's element size when read,
        // which is the constraint that matters for decoding.
        "bufferViews" if rest.starts_with(".byteStride") => Severity::Ignore,
        "bufferViews" => fatal_if(in_set(&geo.views)),
        "buffers" => fatal_if(in_set(&geo.buffers)),
        _ => Severity::Warn,
    }
}

fn problem_text(e: json::validation::Error) -> &'static str {
    use json::validation::Error as V;
    match e {
        V::IndexOutOfBounds => "index out of range",
        V::Invalid => "invalid value",
        V::Missing => "required value missing",
        V::Oversize => "value too large",
        V::Unsupported => "not supported",
    }
}

/// Runs gltf-json's validation and turns geometry-relevant problems into an
/// error and the rest into one summary warning.
fn validate(
    path: &Path,
    root: &json::Root,
    geo: &GeometryRefs,
    warnings: &mut Vec<String>,
) -> Result<()> {
    let mut fatal = Vec::new();
    let mut minor = Vec::new();
    root.validate(
        root,
        json::Path::new,
        &mut |p: &dyn Fn() -> json::Path, e| {
            let p = p().0;
            let line = format!("{p}: {}", problem_text(e));
            match classify_problem(&p, geo) {
                Severity::Ignore => {}
                Severity::Warn => minor.push(line),
                Severity::Fatal => fatal.push(line),
            }
        },
    );
    if let Some(first) = minor.first() {
        warnings.push(format!(
            "ignored {} glTF validation problem(s) that do not affect geometry, e.g. {first}",
            minor.len()
        ));
    }
    if fatal.is_empty() {
        return Ok(());
    }
    let mut msg = format!(
        "invalid glTF: {}",
        fatal[..fatal.len().min(MAX_LISTED_PROBLEMS)].join("; ")
    );
    if fatal.len() > MAX_LISTED_PROBLEMS {
        msg.push_str(&format!(
            " (and {} more)",
            fatal.len() - MAX_LISTED_PROBLEMS
        ));
    }
    Err(Error::input(path, msg))
}

// ---------------------------------------------------------------------------
// Scene graph
// ---------------------------------------------------------------------------

/// Column-major 4x4 matrix in f64, `m[col][row]`, the layout of glTF `matrix`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Mat4([[f64; 4]; 4]);

impl Mat4 {
    const IDENTITY: Mat4 = Mat4([
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]);

    fn from_cols_f32(m: &[f32; 16]) -> Mat4 {
        let mut out = [[0.0; 4]; 4];
        for (i, v) in m.iter().enumerate() {
            out[i / 4][i % 4] = f64::from(*v);
        }
        Mat4(out)
    }

    /// `T * R * S` as the glTF spec defines a node's TRS transform.
    fn from_trs(t: [f32; 3], q: [f32; 4], s: [f32; 3]) -> Mat4 {
        let [x, y, z, w] = q.map(f64::from);
        let [sx, sy, sz] = s.map(f64::from);
        let [tx, ty, tz] = t.map(f64::from);
        Mat4([
            [
                (1.0 - 2.0 * (y * y + z * z)) * sx,
                2.0 * (x * y + z * w) * sx,
                2.0 * (x * z - y * w) * sx,
                0.0,
            ],
            [
                2.0 * (x * y - z * w) * sy,
                (1.0 - 2.0 * (x * x + z * z)) * sy,
                2.0 * (y * z + x * w) * sy,
                0.0,
            ],
            [
                2.0 * (x * z + y * w) * sz,
                2.0 * (y * z - x * w) * sz,
                (1.0 - 2.0 * (x * x + y * y)) * sz,
                0.0,
            ],
            [tx, ty, tz, 1.0],
        ])
    }

    fn mul(&self, rhs: &Mat4) -> Mat4 {
        let mut out = [[0.0; 4]; 4];
        for (col, out_col) in out.iter_mut().enumerate() {
            for (row, v) in out_col.iter_mut().enumerate() {
                *v = (0..4).map(|k| self.0[k][row] * rhs.0[col][k]).sum();
            }
        }
        Mat4(out)
    }

    /// Affine transform of a point in f64, rounded to f32 once.
    #[inline]
    fn transform_point(&self, p: [f64; 3]) -> [f32; 3] {
        let m = &self.0;
        let row = |r: usize| (m[0][r] * p[0] + m[1][r] * p[1] + m[2][r] * p[2] + m[3][r]) as f32;
        [row(0), row(1), row(2)]
    }

    /// Determinant of the linear 3x3 part: negative means mirroring.
    fn det3(&self) -> f64 {
        let [c0, c1, c2] = [self.0[0], self.0[1], self.0[2]];
        c0[0] * (c1[1] * c2[2] - c1[2] * c2[1])
            + c0[1] * (c1[2] * c2[0] - c1[0] * c2[2])
            + c0[2] * (c1[0] * c2[1] - c1[1] * c2[0])
    }
}

fn local_matrix(node: &json::Node) -> Mat4 {
    match &node.matrix {
        Some(m) => Mat4::from_cols_f32(m),
        None => Mat4::from_trs(
            node.translation.unwrap_or([0.0; 3]),
            node.rotation.map_or([0.0, 0.0, 0.0, 1.0], |q| q.0),
            node.scale.unwrap_or([1.0; 3]),
        ),
    }
}

/// One mesh placed in the world.
struct Instance {
    /// The node carrying the mesh (None in the no-scene fallback).
    node: Option<usize>,
    mesh: usize,
    world: Mat4,
}

/// Expands the scene graph into mesh instances, depth first in document
/// order, with an explicit stack so deep hierarchies cannot overflow ours.
fn collect_instances(
    path: &Path,
    root: &json::Root,
    warnings: &mut Vec<String>,
) -> Result<Vec<Instance>> {
    let roots: Vec<usize> = if let Some(s) = root.scene {
        root.scenes
            .get(s.value())
            .map(|sc| sc.nodes.iter().map(|n| n.value()).collect())
            .unwrap_or_default()
    } else if !root.scenes.is_empty() {
        if root.scenes.len() > 1 {
            warnings.push(format!(
                "no default scene; loading all {} scenes",
                root.scenes.len()
            ));
        }
        root.scenes
            .iter()
            .flat_map(|sc| sc.nodes.iter().map(|n| n.value()))
            .collect()
    } else {
        if !root.meshes.is_empty() {
            warnings.push(format!(
                "the file has no scenes; placing each of its {} meshes once at the origin",
                root.meshes.len()
            ));
        }
        return Ok((0..root.meshes.len())
            .map(|mesh| Instance {
                node: None,
                mesh,
                world: Mat4::IDENTITY,
            })
            .collect());
    };

    enum Step {
        Enter(usize, Mat4),
        Leave(usize),
    }
    let mut instances = Vec::new();
    let mut on_path = vec![false; root.nodes.len()];
    let mut stack: Vec<Step> = roots
        .iter()
        .rev()
        .map(|&n| Step::Enter(n, Mat4::IDENTITY))
        .collect();
    let mut visits = 0usize;
    let (mut warned_skin, mut warned_targets) = (false, false);
    while let Some(step) = stack.pop() {
        let (n, parent) = match step {
            Step::Leave(n) => {
                on_path[n] = false;
                continue;
            }
            Step::Enter(n, parent) => (n, parent),
        };
        let (Some(node), Some(flag)) = (root.nodes.get(n), on_path.get_mut(n)) else {
            return Err(Error::input(path, format!("node {n} does not exist")));
        };
        if *flag {
            return Err(Error::input(
                path,
                format!("node {n} is its own ancestor (recursive node graph)"),
            ));
        }
        *flag = true;
        visits += 1;
        if visits > MAX_NODE_VISITS {
            return Err(Error::input(
                path,
                format!(
                    "the node graph expands to more than {MAX_NODE_VISITS} node instances (nodes shared by several parents?)"
                ),
            ));
        }
        stack.push(Step::Leave(n));
        let world = parent.mul(&local_matrix(node));
        if let Some(m) = node.mesh {
            let mesh = m.value();
            if node.skin.is_some() && !warned_skin {
                warned_skin = true;
                warnings.push(format!(
                    "node {n} is skinned; skinning is ignored and meshes are placed by their node transform"
                ));
            }
            let has_targets = root.meshes.get(mesh).is_some_and(|me| {
                me.primitives
                    .iter()
                    .any(|p| p.targets.as_ref().is_some_and(|t| !t.is_empty()))
            });
            if has_targets && !warned_targets {
                warned_targets = true;
                warnings.push(format!(
                    "mesh {mesh} has morph targets; they are ignored (base shape used)"
                ));
            }
            instances.push(Instance {
                node: Some(n),
                mesh,
                world,
            });
        }
        for c in node.children.iter().flatten().rev() {
            stack.push(Step::Enter(c.value(), world));
        }
    }
    Ok(instances)
}

// ---------------------------------------------------------------------------
// Buffers
// ---------------------------------------------------------------------------

/// A buffer's bytes: part of the file (a GLB's BIN chunk), or bytes of its
/// own (a decoded data URI, or an external file, mapped when large).
enum Buffer<'a> {
    Part(&'a [u8]),
    Own(FileBytes),
}

impl std::ops::Deref for Buffer<'_> {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            Buffer::Part(b) => b,
            Buffer::Own(b) => b,
        }
    }
}

/// Reads the buffers in `needed` (in index order, so the digest is
/// deterministic) and checks each holds at least its declared byteLength.
/// Pushes the index of every buffer read from a file to `external`, in the
/// order read: those bytes go into the input's digest after the file's.
fn load_buffers<'a>(
    path: &Path,
    root: &json::Root,
    glb_bin: Option<&'a [u8]>,
    needed: &BTreeSet<usize>,
    external: &mut Vec<usize>,
) -> Result<Vec<Option<Buffer<'a>>>> {
    let mut out: Vec<Option<Buffer<'a>>> = (0..root.buffers.len()).map(|_| None).collect();
    for &b in needed {
        let (Some(buffer), Some(slot)) = (root.buffers.get(b), out.get_mut(b)) else {
            continue; // reported by check_references
        };
        let err = |m: String| Error::input(path, format!("buffer {b}: {m}"));
        let (bytes, source): (Buffer<'a>, String) = match buffer.uri.as_deref() {
            None => match glb_bin {
                Some(bin) if b == 0 => (Buffer::Part(bin), "GLB BIN chunk".to_string()),
                Some(_) => {
                    return Err(err(
                        "has no uri; only buffer 0 of a .glb may refer to the BIN chunk"
                            .to_string(),
                    ));
                }
                None => {
                    return Err(err(
                        "has no uri and the file has no GLB BIN chunk".to_string()
                    ));
                }
            },
            Some(uri) if has_prefix_ignore_case(uri, "data:") => {
                let bytes = decode_data_uri(uri).map_err(|m| err(format!("data URI: {m}")))?;
                (Buffer::Own(bytes.into()), "data URI".to_string())
            }
            Some(uri) => {
                if has_uri_scheme(uri) {
                    return Err(err(format!(
                        "uri {uri:?}: only relative file paths and data: URIs are supported"
                    )));
                }
                let rel = String::from_utf8(percent_decode(uri))
                    .map_err(|_| err(format!("uri {uri:?} is not valid UTF-8 once decoded")))?;
                let file = path.parent().unwrap_or(Path::new("")).join(&rel);
                let bytes = crate::file_bytes::read_or_map(&file)
                    .map_err(|e| err(format!("cannot read {}: {e}", file.display())))?;
                external.push(b);
                (Buffer::Own(bytes), format!("{rel:?}"))
            }
        };
        let declared = buffer.byte_length.0;
        if (bytes.len() as u64) < declared {
            return Err(err(format!(
                "{source} has {} bytes, fewer than the declared byteLength {declared}",
                bytes.len()
            )));
        }
        *slot = Some(bytes);
    }
    Ok(out)
}

fn has_prefix_ignore_case(s: &str, prefix: &str) -> bool {
    s.get(..prefix.len())
        .is_some_and(|p| p.eq_ignore_ascii_case(prefix))
}

/// True for `scheme:...` URIs (http:, file:, ...). A one-letter "scheme" is a
/// Windows drive letter, which we let through as a path.
fn has_uri_scheme(uri: &str) -> bool {
    let Some(colon) = uri.find(':') else {
        return false;
    };
    let scheme = &uri[..colon];
    scheme.len() > 1
        && scheme.starts_with(|c: char| c.is_ascii_alphabetic())
        && scheme
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'))
}

fn decode_data_uri(uri: &str) -> std::result::Result<Vec<u8>, String> {
    let rest = &uri["data:".len()..];
    let (meta, payload) = rest
        .split_once(',')
        .ok_or_else(|| "no ',' separating header and data".to_string())?;
    let is_base64 = meta
        .rsplit(';')
        .next()
        .is_some_and(|p| p.eq_ignore_ascii_case("base64"));
    if is_base64 {
        base64::engine::general_purpose::STANDARD_PAD_INDIFFERENT
            .decode(payload.trim())
            .map_err(|e| format!("invalid base64: {e}"))
    } else {
        Ok(percent_decode(payload))
    }
}

/// Decodes `%XX` escapes (URIs in glTF are URI-encoded, e.g. spaces as %20);
/// malformed escapes are kept literally.
fn percent_decode(s: &str) -> Vec<u8> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let hex = |c: u8| (c as char).to_digit(16);
        if b[i] == b'%'
            && let (Some(h), Some(l)) = (
                b.get(i + 1).and_then(|&c| hex(c)),
                b.get(i + 2).and_then(|&c| hex(c)),
            )
        {
            out.push((h * 16 + l) as u8);
            i += 3;
            continue;
        }
        out.push(b[i]);
        i += 1;
    }
    out
}

// ---------------------------------------------------------------------------
// Accessors
// ---------------------------------------------------------------------------

/// A component type and how to turn its little-endian bytes into f64.
trait Component {
    const SIZE: usize;
    fn get(b: &[u8]) -> f64;
}

macro_rules! component {
    ($name:ident, $ty:ty, $conv:expr) => {
        struct $name;
        impl Component for $name {
            const SIZE: usize = std::mem::size_of::<$ty>();
            #[inline(always)]
            fn get(b: &[u8]) -> f64 {
                let mut a = [0u8; std::mem::size_of::<$ty>()];
                a.copy_from_slice(&b[..Self::SIZE]);
                let conv: fn($ty) -> f64 = $conv;
                conv(<$ty>::from_le_bytes(a))
            }
        }
    };
}

// Normalization per the glTF spec (3.11): signed max(c / MAX, -1), unsigned c / MAX.
component!(F32, f32, f64::from);
component!(I8, i8, f64::from);
component!(U8, u8, f64::from);
component!(I16, i16, f64::from);
component!(U16, u16, f64::from);
component!(U32, u32, f64::from);
component!(I8Norm, i8, |c| (f64::from(c) / 127.0).max(-1.0));
component!(U8Norm, u8, |c| f64::from(c) / 255.0);
component!(I16Norm, i16, |c| (f64::from(c) / 32767.0).max(-1.0));
component!(U16Norm, u16, |c| f64::from(c) / 65535.0);
component!(U32Norm, u32, |c| f64::from(c) / 4_294_967_295.0);

/// Decodes `count` elements of `N` components, element `i` starting at
/// `i * stride`. The caller guarantees `bytes` holds them all.
#[inline(always)]
fn run<const N: usize, C: Component>(
    bytes: &[u8],
    stride: usize,
    count: usize,
    sink: &mut impl FnMut(usize, [f64; N]),
) {
    debug_assert!(count == 0 || bytes.len() >= (count - 1) * stride + N * C::SIZE);
    for i in 0..count {
        let base = i * stride;
        let mut v = [0.0; N];
        for (k, out) in v.iter_mut().enumerate() {
            *out = C::get(&bytes[base + k * C::SIZE..]);
        }
        sink(i, v);
    }
}

/// Reads the integer scalars of a dense accessor (`out.len()` elements,
/// element `i` at `i * stride`) straight into `out`, for the unsigned
/// component types indices may have; false (nothing written) for any other.
///
/// Why: the general path converts every value to f64 and back, with a
/// bounds check per component, and on the 871k-triangle dragon that loop
/// was the largest part of building the soup (a quarter of its profile
/// samples). The values are the same: an unsigned integer converts to f64
/// and back to u32 exactly.
fn dense_indices(comp: ComponentType, bytes: &[u8], stride: usize, out: &mut [u32]) -> bool {
    fn read<const S: usize>(
        bytes: &[u8],
        stride: usize,
        out: &mut [u32],
        conv: fn([u8; S]) -> u32,
    ) {
        if stride == S {
            for (o, c) in out.iter_mut().zip(bytes.chunks_exact(S)) {
                *o = conv(c.try_into().unwrap());
            }
        } else {
            for (i, o) in out.iter_mut().enumerate() {
                *o = conv(bytes[i * stride..i * stride + S].try_into().unwrap());
            }
        }
    }
    match comp {
        ComponentType::U8 => read::<1>(bytes, stride, out, |b| u32::from(b[0])),
        ComponentType::U16 => read::<2>(bytes, stride, out, |b| u32::from(u16::from_le_bytes(b))),
        ComponentType::U32 => read::<4>(bytes, stride, out, u32::from_le_bytes),
        _ => return false,
    }
    true
}

/// Copies the f32 VEC3 elements of a dense accessor (`out.len()` of them,
/// element `i` at `i * stride`) into `out`. The same values as the general
/// path's f32 → f64 → f32, which is exact, without its per-component
/// conversions and bounds checks (except that a signalling NaN keeps its
/// bits here, where the round trip quiets it; both are rejected alike).
fn dense_f32x3(bytes: &[u8], stride: usize, out: &mut [[f32; 3]]) {
    let get = |b: &[u8]| f32::from_le_bytes(b.try_into().unwrap());
    let one = |e: &[u8]| [get(&e[0..4]), get(&e[4..8]), get(&e[8..12])];
    if stride == 12 {
        for (o, e) in out.iter_mut().zip(bytes.chunks_exact(12)) {
            *o = one(e);
        }
    } else {
        for (i, o) in out.iter_mut().enumerate() {
            *o = one(&bytes[i * stride..i * stride + 12]);
        }
    }
}

/// Dispatches on the component type once, so the per-element loop is
/// monomorphic and tight.
fn decode_elements<const N: usize>(
    comp: ComponentType,
    normalized: bool,
    bytes: &[u8],
    stride: usize,
    count: usize,
    sink: &mut impl FnMut(usize, [f64; N]),
) {
    use ComponentType as T;
    match (comp, normalized) {
        (T::F32, _) => run::<N, F32>(bytes, stride, count, sink),
        (T::I8, false) => run::<N, I8>(bytes, stride, count, sink),
        (T::I8, true) => run::<N, I8Norm>(bytes, stride, count, sink),
        (T::U8, false) => run::<N, U8>(bytes, stride, count, sink),
        (T::U8, true) => run::<N, U8Norm>(bytes, stride, count, sink),
        (T::I16, false) => run::<N, I16>(bytes, stride, count, sink),
        (T::I16, true) => run::<N, I16Norm>(bytes, stride, count, sink),
        (T::U16, false) => run::<N, U16>(bytes, stride, count, sink),
        (T::U16, true) => run::<N, U16Norm>(bytes, stride, count, sink),
        (T::U32, false) => run::<N, U32>(bytes, stride, count, sink),
        (T::U32, true) => run::<N, U32Norm>(bytes, stride, count, sink),
    }
}

fn component_name(c: ComponentType) -> &'static str {
    match c {
        ComponentType::I8 => "BYTE",
        ComponentType::U8 => "UNSIGNED_BYTE",
        ComponentType::I16 => "SHORT",
        ComponentType::U16 => "UNSIGNED_SHORT",
        ComponentType::U32 => "UNSIGNED_INT",
        ComponentType::F32 => "FLOAT",
    }
}

fn type_name(t: Type) -> &'static str {
    match t {
        Type::Scalar => "SCALAR",
        Type::Vec2 => "VEC2",
        Type::Vec3 => "VEC3",
        Type::Vec4 => "VEC4",
        Type::Mat2 => "MAT2",
        Type::Mat3 => "MAT3",
        Type::Mat4 => "MAT4",
    }
}

/// An accessor with every byte range bounds-checked, ready to decode.
struct Source<'s> {
    accessor: usize,
    count: usize,
    comp: ComponentType,
    normalized: bool,
    /// Element bytes and stride; None means all zeros (sparse-only accessor).
    dense: Option<(&'s [u8], usize)>,
    sparse: Option<SparseSource<'s>>,
}

struct SparseSource<'s> {
    count: usize,
    index_comp: ComponentType,
    indices: &'s [u8],
    values: &'s [u8],
}

/// Everything element decoding needs: the document and its loaded buffers.
struct Ctx<'a> {
    path: &'a Path,
    root: &'a json::Root,
    buffers: Vec<Option<Buffer<'a>>>,
}

impl Ctx<'_> {
    fn err(&self, msg: String) -> Error {
        Error::input(self.path, msg)
    }

    /// The bytes of a buffer view (checked against its buffer) and its stride.
    fn view(&self, v: usize) -> Result<(&[u8], Option<usize>)> {
        let view = self
            .root
            .buffer_views
            .get(v)
            .ok_or_else(|| self.err(format!("bufferView {v} does not exist")))?;
        let b = view.buffer.value();
        let declared = self.root.buffers.get(b).map_or(0, |buf| buf.byte_length.0);
        let data = self
            .buffers
            .get(b)
            .and_then(|d| d.as_deref())
            .ok_or_else(|| self.err(format!("buffer {b} (of bufferView {v}) was not loaded")))?;
        let offset = view.byte_offset.map_or(0, |o| o.0);
        let len = view.byte_length.0;
        let end = offset.checked_add(len).filter(|&e| e <= declared);
        let bytes = end
            .and_then(|e| data.get(usize::try_from(offset).ok()?..usize::try_from(e).ok()?))
            .ok_or_else(|| {
                self.err(format!(
                    "bufferView {v} (byteOffset {offset}, byteLength {len}) extends past the end of buffer {b} (byteLength {declared})"
                ))
            })?;
        Ok((bytes, view.byte_stride.map(|s| s.0)))
    }

    /// Bounds-checks accessor `a` for elements of `n` components; `what`
    /// says who uses it, for messages.
    fn resolve(&self, a: usize, n: usize, what: &str) -> Result<Source<'_>> {
        let acc = self
            .root
            .accessors
            .get(a)
            .ok_or_else(|| self.err(format!("{what}: accessor {a} does not exist")))?;
        let Checked::Valid(comp) = acc.component_type else {
            return Err(self.err(format!("{what}: accessor {a} has an invalid componentType")));
        };
        let comp = comp.0;
        let count = acc.count.0;
        let elem = (comp.size() * n) as u64;
        let dense = match acc.buffer_view {
            Some(v) => {
                let v = v.value();
                let (bytes, stride) = self.view(v)?;
                let stride = stride.map_or(elem, |s| s as u64);
                if stride < elem {
                    return Err(self.err(format!(
                        "{what}: bufferView {v} byteStride {stride} is smaller than accessor {a}'s element size {elem}"
                    )));
                }
                let offset = acc.byte_offset.map_or(0, |o| o.0);
                let need = if count == 0 {
                    Some(offset)
                } else {
                    (count - 1)
                        .checked_mul(stride)
                        .and_then(|x| x.checked_add(elem))
                        .and_then(|x| x.checked_add(offset))
                };
                let slice = need
                    .filter(|&e| e <= bytes.len() as u64)
                    .and_then(|e| bytes.get(offset as usize..e as usize))
                    .ok_or_else(|| {
                        let need = need.map_or("more than 2^64".to_string(), |x| x.to_string());
                        self.err(format!(
                            "{what}: accessor {a} (byteOffset {offset}, count {count}, {elem}-byte elements every {stride} bytes) needs {need} bytes of bufferView {v}, which has only {}",
                            bytes.len()
                        ))
                    })?;
                Some((slice, stride as usize))
            }
            None => {
                if acc.sparse.is_none() {
                    return Err(self.err(format!(
                        "{what}: accessor {a} has neither a bufferView nor sparse data"
                    )));
                }
                if count > MAX_UNBACKED_COUNT {
                    return Err(self.err(format!(
                        "{what}: accessor {a} has no bufferView and count {count}, above the limit of {MAX_UNBACKED_COUNT} for data that is not in the file"
                    )));
                }
                None
            }
        };
        let sparse = match &acc.sparse {
            None => None,
            Some(s) => {
                let scount = s.count.0;
                if scount > count {
                    return Err(self.err(format!(
                        "{what}: accessor {a} has sparse count {scount}, more than its count {count}"
                    )));
                }
                let Checked::Valid(ic) = s.indices.component_type else {
                    return Err(self.err(format!(
                        "{what}: accessor {a} has an invalid sparse.indices.componentType"
                    )));
                };
                let index_comp = ic.0;
                let part = |v: usize, offset: u64, size: u64, name: &str| -> Result<&[u8]> {
                    let (bytes, _) = self.view(v)?;
                    // `scount <= count`, which is bounded, so no overflow.
                    let len = scount * size;
                    offset
                        .checked_add(len)
                        .filter(|&e| e <= bytes.len() as u64)
                        .and_then(|e| bytes.get(offset as usize..e as usize))
                        .ok_or_else(|| {
                            self.err(format!(
                                "{what}: accessor {a} sparse {name} need {len} bytes at byteOffset {offset} of bufferView {v}, which has only {}",
                                bytes.len()
                            ))
                        })
                };
                Some(SparseSource {
                    count: scount as usize,
                    index_comp,
                    indices: part(
                        s.indices.buffer_view.value(),
                        s.indices.byte_offset.0,
                        index_comp.size() as u64,
                        "indices",
                    )?,
                    values: part(
                        s.values.buffer_view.value(),
                        s.values.byte_offset.0,
                        elem,
                        "values",
                    )?,
                })
            }
        };
        Ok(Source {
            accessor: a,
            count: count as usize,
            comp,
            normalized: acc.normalized,
            dense,
            sparse,
        })
    }

    /// Decodes every element of `src` into `sink(index, value)`: the dense
    /// (or zero) base first, then sparse overrides, which may hit an index a
    /// second time. Sparse indices are checked against the count.
    fn decode<const N: usize>(
        &self,
        src: &Source<'_>,
        what: &str,
        sink: &mut impl FnMut(usize, [f64; N]),
    ) -> Result<()> {
        match src.dense {
            Some((bytes, stride)) => {
                decode_elements::<N>(src.comp, src.normalized, bytes, stride, src.count, sink)
            }
            None => (0..src.count).for_each(|i| sink(i, [0.0; N])),
        }
        let Some(sp) = &src.sparse else {
            return Ok(());
        };
        let mut targets = Vec::with_capacity(sp.count);
        let size = sp.index_comp.size();
        decode_elements::<1>(
            sp.index_comp,
            false,
            sp.indices,
            size,
            sp.count,
            &mut |_, v| targets.push(v[0] as usize),
        );
        if let Some((j, &t)) = targets.iter().enumerate().find(|(_, t)| **t >= src.count) {
            return Err(self.err(format!(
                "{what}: accessor {} sparse index {t} (entry {j}) is out of range (count {})",
                src.accessor, src.count
            )));
        }
        let elem = src.comp.size() * N;
        decode_elements::<N>(
            src.comp,
            src.normalized,
            sp.values,
            elem,
            sp.count,
            &mut |j, v| sink(targets[j], v),
        );
        Ok(())
    }

    /// [`Ctx::decode`] of an indices accessor into `out` (`src.count`
    /// long). A dense accessor without sparse entries is read straight into
    /// `out` (`dense_indices`); anything else goes through `decode`.
    fn decode_indices(&self, src: &Source<'_>, what: &str, out: &mut [u32]) -> Result<()> {
        if let (Some((bytes, stride)), None) = (src.dense, &src.sparse)
            && dense_indices(src.comp, bytes, stride, out)
        {
            return Ok(());
        }
        self.decode::<1>(src, what, &mut |i, v| out[i] = v[0] as u32)
    }

    /// [`Ctx::decode`] of a POSITION accessor into `out` (`src.count`
    /// long), untransformed. A dense FLOAT accessor without sparse entries
    /// is copied straight into `out` (`dense_f32x3`); anything else goes
    /// through `decode`.
    fn decode_positions(&self, src: &Source<'_>, what: &str, out: &mut [[f32; 3]]) -> Result<()> {
        if let (Some((bytes, stride)), None, ComponentType::F32) =
            (src.dense, &src.sparse, src.comp)
        {
            dense_f32x3(bytes, stride, out);
            return Ok(());
        }
        // Also keeps an Inf coordinate from turning others into NaN
        // through Inf * 0 terms (no transform here).
        self.decode::<3>(src, what, &mut |i, v| {
            out[i] = [v[0] as f32, v[1] as f32, v[2] as f32]
        })
    }

    /// Resolves a POSITION accessor, insisting on VEC3 and a component type
    /// glTF (with KHR_mesh_quantization) allows for positions.
    fn resolve_positions(&self, a: usize, what: &str) -> Result<Source<'_>> {
        let acc = self
            .root
            .accessors
            .get(a)
            .ok_or_else(|| self.err(format!("{what}: POSITION accessor {a} does not exist")))?;
        match acc.type_ {
            Checked::Valid(Type::Vec3) => {}
            Checked::Valid(t) => {
                return Err(self.err(format!(
                    "{what}: POSITION accessor {a} has type {}, expected VEC3",
                    type_name(t)
                )));
            }
            Checked::Invalid => {
                return Err(self.err(format!(
                    "{what}: POSITION accessor {a} has an invalid type, expected VEC3"
                )));
            }
        }
        if let Checked::Valid(c) = acc.component_type
            && c.0 == ComponentType::U32
        {
            return Err(self.err(format!(
                "{what}: POSITION accessor {a} has componentType UNSIGNED_INT, which glTF does not allow for positions"
            )));
        }
        self.resolve(a, 3, what)
    }

    /// Resolves an index accessor: SCALAR of an unsigned integer type.
    fn resolve_indices(&self, a: usize, what: &str) -> Result<Source<'_>> {
        let acc = self
            .root
            .accessors
            .get(a)
            .ok_or_else(|| self.err(format!("{what}: indices accessor {a} does not exist")))?;
        match acc.type_ {
            Checked::Valid(Type::Scalar) => {}
            Checked::Valid(t) => {
                return Err(self.err(format!(
                    "{what}: indices accessor {a} has type {}, expected SCALAR",
                    type_name(t)
                )));
            }
            Checked::Invalid => {
                return Err(self.err(format!(
                    "{what}: indices accessor {a} has an invalid type, expected SCALAR"
                )));
            }
        }
        if let Checked::Valid(c) = acc.component_type
            && !matches!(
                c.0,
                ComponentType::U8 | ComponentType::U16 | ComponentType::U32
            )
        {
            return Err(self.err(format!(
                "{what}: indices accessor {a} has componentType {}; indices must be UNSIGNED_BYTE, UNSIGNED_SHORT or UNSIGNED_INT",
                component_name(c.0)
            )));
        }
        let mut src = self.resolve(a, 1, what)?;
        // "normalized" is meaningless for indices; never scale them.
        src.normalized = false;
        Ok(src)
    }
}

// ---------------------------------------------------------------------------
// Triangles
// ---------------------------------------------------------------------------

fn triangle_count(mode: Mode, n: usize) -> usize {
    match mode {
        Mode::Triangles => n / 3,
        Mode::TriangleStrip | Mode::TriangleFan => n.saturating_sub(2),
        _ => 0,
    }
}

/// Appends the triangles of `n` vertices (`at(i)` = the i-th one, already
/// offset into the soup), following the glTF spec (3.7.2.1):
/// strips `p_i = {v_i, v_{i+(1+i%2)}, v_{i+(2-i%2)}}` (for odd i that is
/// (i, i+2, i+1), the same orientation as (i+1, i, i+2)) and fans
/// `p_i = {v_{i+1}, v_{i+2}, v_0}`. `flip` swaps two corners for mirroring
/// transforms.
fn emit_triangles(mode: Mode, n: usize, at: impl Fn(usize) -> u32, flip: bool, out: &mut Vec<u32>) {
    let mut push = |a: u32, b: u32, c: u32| {
        if flip {
            out.extend_from_slice(&[a, c, b]);
        } else {
            out.extend_from_slice(&[a, b, c]);
        }
    };
    match mode {
        Mode::Triangles => (0..n / 3).for_each(|t| push(at(3 * t), at(3 * t + 1), at(3 * t + 2))),
        Mode::TriangleStrip => (0..n.saturating_sub(2)).for_each(|i| {
            let odd = i % 2;
            push(at(i), at(i + 1 + odd), at(i + 2 - odd));
        }),
        Mode::TriangleFan => {
            (0..n.saturating_sub(2)).for_each(|i| push(at(i + 1), at(i + 2), at(0)))
        }
        _ => {}
    }
}

fn label(kind: &str, index: usize, name: Option<&str>) -> String {
    match name {
        Some(n) if !n.is_empty() => format!("{kind} {n:?}"),
        _ => format!("{kind} {index}"),
    }
}

/// "mesh 1 \"Tire\" primitive 0" for error messages.
fn primitive_desc(root: &json::Root, m: usize, p: usize) -> String {
    match root.meshes.get(m).and_then(|me| me.name.as_deref()) {
        Some(name) if !name.is_empty() => format!("mesh {m} {name:?} primitive {p}"),
        _ => format!("mesh {m} primitive {p}"),
    }
}

/// Reserves the soup's final size before anything is decoded, so its two
/// vectors are allocated once. Growing them primitive by primitive copied
/// and faulted in the data again at every doubling: about a fifth of the
/// load on 2CylinderEngine, which instances many small primitives. Only
/// primitives whose accessors resolve (in bounds of their buffers) count, so
/// a bogus `count` cannot make us reserve memory the file could not fill;
/// whatever is wrong is left for `build_soup` to report.
fn reserve_soup(ctx: &Ctx<'_>, instances: &[Instance], soup: &mut Soup) {
    let (mut vertices, mut corners) = (0usize, 0usize);
    for inst in instances {
        let Some(mesh) = ctx.root.meshes.get(inst.mesh) else {
            continue;
        };
        for prim in &mesh.primitives {
            let Checked::Valid(mode) = prim.mode else {
                continue;
            };
            let Some(Ok(pos)) = position_accessor(prim).map(|a| ctx.resolve_positions(a, ""))
            else {
                continue;
            };
            let n = match prim.indices.map(|ia| ctx.resolve_indices(ia.value(), "")) {
                Some(Ok(idx)) => idx.count,
                Some(Err(_)) => continue,
                None => pos.count,
            };
            let tris = triangle_count(mode, n);
            if tris > 0 {
                vertices = vertices.saturating_add(pos.count);
                corners = corners.saturating_add(tris.saturating_mul(3));
            }
        }
    }
    // Past these the build fails anyway (32-bit vertex and triangle ids).
    let _ = soup
        .positions
        .try_reserve_exact(vertices.min(u32::MAX as usize));
    let _ = soup
        .indices
        .try_reserve_exact(corners.min(3 * u32::MAX as usize));
}

fn build_soup(
    ctx: &Ctx<'_>,
    instances: &[Instance],
    soup: &mut Soup,
    warnings: &mut Vec<String>,
) -> Result<()> {
    let root = ctx.root;
    // Index scratch, reused so a primitive instance costs no allocation.
    let mut scratch: Vec<u32> = Vec::new();
    let mut warned_leftover = BTreeSet::new();
    for inst in instances {
        let mesh = root
            .meshes
            .get(inst.mesh)
            .ok_or_else(|| ctx.err(format!("mesh {} does not exist", inst.mesh)))?;
        let flip = inst.world.det3() < 0.0;
        let identity = inst.world == Mat4::IDENTITY;
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            let what = primitive_desc(root, inst.mesh, pi);
            let Checked::Valid(mode) = prim.mode else {
                return Err(ctx.err(format!("{what} has an invalid mode")));
            };
            match mode {
                Mode::Points => {
                    soup.stats.skipped_points += 1;
                    continue;
                }
                Mode::Lines | Mode::LineLoop | Mode::LineStrip => {
                    soup.stats.skipped_lines += 1;
                    continue;
                }
                Mode::Triangles | Mode::TriangleStrip | Mode::TriangleFan => {}
            }
            let pos_acc = position_accessor(prim)
                .ok_or_else(|| ctx.err(format!("{what} has no POSITION attribute")))?;
            let pos = ctx.resolve_positions(pos_acc, &what)?;
            let vcount = pos.count;

            // Indices first: an out-of-range index rejects the file before
            // we spend memory on its positions. A plain triangle list is
            // decoded straight onto the end of the soup's indices, where it
            // stays (its vertex offset added in place below); anything else
            // into `scratch`. Why: a copy of the largest array of the load
            // (10 MB of fresh memory for the 871k-triangle dragon) and a
            // pass over it.
            let direct = prim.indices.is_some() && mode == Mode::Triangles && !flip;
            let first = soup.indices.len() / 3;
            let n = match prim.indices {
                Some(ia) => {
                    let ia = ia.value();
                    let src = ctx.resolve_indices(ia, &what)?;
                    let buf = if direct {
                        &mut soup.indices
                    } else {
                        scratch.clear();
                        &mut scratch
                    };
                    let at = buf.len();
                    buf.try_reserve(src.count).map_err(|_| {
                        ctx.err(format!(
                            "out of memory reserving {} indices for {what}",
                            src.count
                        ))
                    })?;
                    buf.resize(at + src.count, 0);
                    let decoded = &mut buf[at..];
                    ctx.decode_indices(&src, &what, decoded)?;
                    // A fold vectorises (`max()` tracks a reference and does
                    // not); the search runs only on failure.
                    if decoded.iter().fold(0, |m, &i| m.max(i)) as usize >= vcount
                        && !decoded.is_empty()
                        && let Some((j, &bad)) = decoded
                            .iter()
                            .enumerate()
                            .find(|(_, x)| **x as usize >= vcount)
                    {
                        return Err(ctx.err(format!(
                            "{what}: index {bad} (element {j} of indices accessor {ia}) is out of range; POSITION accessor {pos_acc} has {vcount} vertices"
                        )));
                    }
                    src.count
                }
                None => vcount,
            };
            if mode == Mode::Triangles
                && !n.is_multiple_of(3)
                && warned_leftover.insert((inst.mesh, pi))
            {
                warnings.push(format!(
                    "{what}: {n} {} is not a multiple of 3; ignoring the last {}",
                    if prim.indices.is_some() {
                        "indices"
                    } else {
                        "vertices"
                    },
                    n % 3
                ));
            }

            let base = soup.positions.len();
            if base + vcount > u32::MAX as usize {
                return Err(ctx.err(format!(
                    "more than {} vertices after instancing (at {what}); svpack indexes vertices with 32 bits",
                    u32::MAX
                )));
            }
            soup.positions.try_reserve(vcount).map_err(|_| {
                ctx.err(format!(
                    "out of memory reserving {vcount} vertices for {what}"
                ))
            })?;
            soup.positions.resize(base + vcount, [0.0; 3]);
            let out = &mut soup.positions[base..];
            if identity {
                ctx.decode_positions(&pos, &what, out)?;
            } else {
                let m = &inst.world;
                ctx.decode::<3>(&pos, &what, &mut |i, v| out[i] = m.transform_point(v))?;
            }

            let tris = triangle_count(mode, n);
            if first + tris > u32::MAX as usize {
                return Err(ctx.err(format!(
                    "more than {} triangles after instancing (at {what})",
                    u32::MAX
                )));
            }
            if !direct {
                soup.indices.try_reserve(tris * 3).map_err(|_| {
                    ctx.err(format!(
                        "out of memory reserving {tris} triangles for {what}"
                    ))
                })?;
            }
            // `base + vcount` fits in u32 (checked above).
            let base32 = base as u32;
            if direct {
                // Already in place: drop a leftover index or two, and
                // offset the rest in one pass (which vectorises).
                soup.indices.truncate(3 * (first + tris));
                if base32 != 0 {
                    soup.indices[3 * first..]
                        .iter_mut()
                        .for_each(|i| *i += base32);
                }
            } else if prim.indices.is_some() {
                let idx = &scratch;
                emit_triangles(mode, n, |i| base32 + idx[i], flip, &mut soup.indices);
            } else {
                emit_triangles(mode, n, |i| base32 + i as u32, flip, &mut soup.indices);
            }

            let node_label = inst.node.map(|ni| {
                label(
                    "node",
                    ni,
                    root.nodes.get(ni).and_then(|n| n.name.as_deref()),
                )
            });
            let mesh_label = label("mesh", inst.mesh, mesh.name.as_deref());
            let name = match node_label {
                Some(nl) => format!("{nl} > {mesh_label} > primitive {pi}"),
                None => format!("{mesh_label} > primitive {pi}"),
            };
            soup.parts.push(Part {
                name,
                first_triangle: first as u32,
                triangle_count: tris as u32,
            });
            soup.stats.primitives += 1;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic bytes (xorshift), so failures reproduce.
    fn noise(n: usize, mut x: u64) -> Vec<u8> {
        (0..n)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x as u8
            })
            .collect()
    }

    #[test]
    fn dense_fast_paths_read_what_the_general_path_reads() {
        let count = 37;
        for (comp, size) in [
            (ComponentType::U8, 1),
            (ComponentType::U16, 2),
            (ComponentType::U32, 4),
        ] {
            // Tightly packed, and interleaved with other data.
            for stride in [size, size + 3, 12] {
                let bytes = noise(
                    (count - 1) * stride + size,
                    stride as u64 * 31 + size as u64,
                );
                let mut general = vec![0u32; count];
                decode_elements::<1>(comp, false, &bytes, stride, count, &mut |i, v| {
                    general[i] = v[0] as u32
                });
                let mut fast = vec![0u32; count];
                assert!(dense_indices(comp, &bytes, stride, &mut fast));
                assert_eq!(fast, general, "{comp:?}, stride {stride}");
            }
        }
        // Not an index type: left to the general path.
        let mut out = [7u32; 2];
        assert!(!dense_indices(ComponentType::F32, &[0; 8], 4, &mut out));
        assert_eq!(out, [7, 7]);

        for stride in [12, 16, 28] {
            // Any bits but NaNs, whose signalling bit the round trip may
            // change (so NaNs are compared as NaNs).
            let bytes = noise((count - 1) * stride + 12, stride as u64);
            let mut general = vec![[0f32; 3]; count];
            decode_elements::<3>(
                ComponentType::F32,
                false,
                &bytes,
                stride,
                count,
                &mut |i, v| general[i] = [v[0] as f32, v[1] as f32, v[2] as f32],
            );
            let mut fast = vec![[0f32; 3]; count];
            dense_f32x3(&bytes, stride, &mut fast);
            for (f, g) in fast.iter().flatten().zip(general.iter().flatten()) {
                assert!(
                    f.to_bits() == g.to_bits() || (f.is_nan() && g.is_nan()),
                    "stride {stride}: {f} against {g}"
                );
            }
        }
    }

    #[test]
    fn extension_classes() {
        use ExtensionKind::*;
        assert_eq!(classify_extension("KHR_mesh_quantization"), Handled);
        assert_eq!(classify_extension("KHR_materials_unlit"), NoGeometry);
        assert_eq!(classify_extension("KHR_texture_transform"), NoGeometry);
        assert_eq!(classify_extension("EXT_texture_webp"), NoGeometry);
        assert_eq!(classify_extension("KHR_draco_mesh_compression"), Geometry);
        assert_eq!(classify_extension("EXT_meshopt_compression"), Geometry);
        assert_eq!(classify_extension("FOO_bar"), Geometry);
    }

    #[test]
    fn validation_paths() {
        let geo = GeometryRefs {
            accessors: [2].into(),
            views: [1].into(),
            buffers: [0].into(),
        };
        assert_eq!(split_path("meshes[2].mode"), ("meshes", Some(2), ".mode"));
        assert_eq!(split_path("scene"), ("scene", None, ""));
        let c = |p| classify_problem(p, &geo);
        assert_eq!(c("accessors[2].componentType"), Severity::Fatal);
        assert_eq!(c("accessors[3].componentType"), Severity::Warn);
        assert_eq!(c("bufferViews[1].byteStride"), Severity::Ignore);
        assert_eq!(
            c("meshes[0].primitives[0].attributes[\"POSITION\"].min"),
            Severity::Ignore
        );
        assert_eq!(c("meshes[0].primitives[0].mode"), Severity::Fatal);
        assert_eq!(c("meshes[0].primitives[0].material"), Severity::Warn);
        assert_eq!(c("materials[0].pbrMetallicRoughness"), Severity::Warn);
        assert_eq!(c("extensionsRequired[0] = \"X\""), Severity::Ignore);
    }

    #[test]
    fn percent_and_scheme() {
        assert_eq!(percent_decode("a%20b%zz"), b"a b%zz");
        assert!(has_uri_scheme("http://x/y.bin"));
        assert!(!has_uri_scheme("C:/x.bin"));
        assert!(!has_uri_scheme("dir/x.bin"));
    }

    #[test]
    fn trs_matches_hand_computed() {
        // 180 degrees about Z, scale (2,3,4), translation (1,2,3).
        let m = Mat4::from_trs([1.0, 2.0, 3.0], [0.0, 0.0, 1.0, 0.0], [2.0, 3.0, 4.0]);
        assert_eq!(m.transform_point([1.0, 1.0, 1.0]), [-1.0, -1.0, 7.0]);
        assert!(m.det3() > 0.0);
        let mirror = Mat4::from_trs([0.0; 3], [0.0, 0.0, 0.0, 1.0], [-1.0, 1.0, 1.0]);
        assert!(mirror.det3() < 0.0);
    }
}
