//! format-spec/README.md §8: the test vector. Rebuilds fixtures/quad.obj and
//! compares with the hex dump in the spec byte for byte, then decodes the file
//! with a reader written from the spec's field list alone (no bincode) and
//! compares with the decoded values the spec lists.
//! `SVPACK_BLESS=1 cargo test --test spec_vector` rewrites the spec section.

mod common;

use std::fmt::Write;

const BEGIN: &str = "<!-- test-vector:begin -->";
const END: &str = "<!-- test-vector:end -->";

/// Minimal cursor following format-spec/README.md §3.
struct Cur<'a> {
    b: &'a [u8],
    at: usize,
}

impl Cur<'_> {
    fn take(&mut self, n: usize) -> &[u8] {
        let s = &self.b[self.at..self.at + n];
        self.at += n;
        s
    }
    fn u8(&mut self) -> u8 {
        self.take(1)[0]
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take(4).try_into().unwrap())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take(8).try_into().unwrap())
    }
    fn f32x3(&mut self) -> String {
        let v: Vec<String> = (0..3)
            .map(|_| format!("{:?}", f32::from_le_bytes(self.take(4).try_into().unwrap())))
            .collect();
        format!("[{}]", v.join(", "))
    }
    fn string(&mut self) -> String {
        let n = self.u64() as usize;
        String::from_utf8(self.take(n).to_vec()).unwrap()
    }
}

/// Decodes the file per the spec into "field = value" lines.
fn decode_per_spec(file: &[u8]) -> Vec<String> {
    let mut out = Vec::new();
    let mut kv = |k: &str, v: String| out.push(format!("{k} = {v}"));
    assert_eq!(&file[0..8], b"SVPK\r\n\x1a\n");
    let mut c = Cur { b: file, at: 8 };
    kv("version_major", c.u16x().to_string());
    kv("version_minor", c.u16x().to_string());
    let hlen = c.u32();
    kv("header_len", hlen.to_string());
    kv("header_crc32", format!("0x{:08x}", c.u32()));
    kv("flags", c.u32().to_string());
    assert_eq!(c.at, 24);
    let payload_offset = c.u64();
    kv("payload_offset", payload_offset.to_string());
    kv("payload_len", c.u64().to_string());
    kv("payload_crc32", format!("0x{:08x}", c.u32()));
    kv("generator", format!("{:?}", c.string()));
    kv("input.file_name", format!("{:?}", c.string()));
    kv("input.format", format!("{:?}", c.string()));
    kv("input.bytes", c.u64().to_string());
    let sha: String = c.take(32).iter().map(|b| format!("{b:02x}")).collect();
    kv("input.sha256", sha);
    kv("options.max_mult", c.u32().to_string());
    kv("options.compress", c.u8().to_string());
    kv("options.positions", c.u8().to_string());
    kv("bounds_min", c.f32x3());
    kv("bounds_max", c.f32x3());
    let meshes = c.u64();
    kv("meshes", meshes.to_string());
    let mut sections = Vec::new();
    for m in 0..meshes {
        let p = format!("meshes[{m}]");
        kv(&format!("{p}.name"), format!("{:?}", c.string()));
        kv(&format!("{p}.bounds_min"), c.f32x3());
        kv(&format!("{p}.bounds_max"), c.f32x3());
        kv(&format!("{p}.position_offset"), c.f32x3());
        kv(&format!("{p}.position_scale"), c.f32x3());
        for f in [
            "primitives",
            "input_triangles",
            "input_vertices",
            "welded_vertices",
            "degenerate_triangles",
            "skipped_points",
            "skipped_lines",
            "triangles",
            "edges",
            "edge_instances",
            "open_edges",
            "non_manifold_edges",
        ] {
            kv(&format!("{p}.stats.{f}"), c.u64().to_string());
        }
        kv(&format!("{p}.stats.max_fan"), c.u32().to_string());
        let h = c.u64();
        let bars: Vec<String> = (0..h).map(|_| format!("{}:{}", c.u32(), c.u64())).collect();
        kv(
            &format!("{p}.stats.histogram"),
            format!("[{}]", bars.join(", ")),
        );
        let (off, len, count) = (c.u64(), c.u64(), c.u64());
        kv(
            &format!("{p}.caps"),
            format!("offset {off}, length {len}, count {count}"),
        );
        sections.push(("caps".to_string(), 3usize, count, off));
        let nb = c.u64();
        for _ in 0..nb {
            let (k, inst, off, len) = (c.u32(), c.u64(), c.u64(), c.u64());
            kv(
                &format!("{p}.bucket k={k}"),
                format!("instances {inst}, offset {off}, length {len}"),
            );
            sections.push((format!("sides k={k}"), 2 + k as usize, inst, off));
        }
    }
    let reserved = c.u64();
    kv("reserved", reserved.to_string());
    assert!(
        c.take(reserved as usize).iter().all(|&b| b == 0),
        "reserved room not zero"
    );
    assert_eq!(
        c.at,
        24 + hlen as usize,
        "header fields do not fill header_len"
    );
    assert_eq!(payload_offset % 16, 0);
    let mut records: Vec<(String, Vec<[f32; 4]>)> = Vec::new();
    for (name, vecs, count, off) in sections {
        for r in 0..count as usize {
            let rec: Vec<[f32; 4]> = (0..vecs)
                .map(|v| {
                    let at = off as usize + (r * vecs + v) * 16;
                    std::array::from_fn(|i| {
                        f32::from_le_bytes(file[at + 4 * i..at + 4 * i + 4].try_into().unwrap())
                    })
                })
                .collect();
            let mut line = format!("{name} record {r}:");
            for v in &rec {
                let _ = write!(line, " ({:?}, {:?}, {:?}, {:?})", v[0], v[1], v[2], v[3]);
            }
            out.push(line);
            records.push((format!("{name} record {r}"), rec));
        }
    }
    // The float contract on this data (format-spec/multiplicity.md): cap sign
    // c and side multiplicity m for three lights.
    use svpack::multiplicity::tri_sign;
    let xyz = |v: [f32; 4]| [v[0], v[1], v[2]];
    for light in [
        [0.25, 0.5, 2.0, 1.0],
        [0.0, 0.0, 1.0, 0.0],
        [3.0, 0.5, 0.0, 1.0],
    ] {
        let vals: Vec<String> = records
            .iter()
            .map(|(name, rec)| {
                if name.starts_with("caps") {
                    format!(
                        "{name}: c = {}",
                        tri_sign(xyz(rec[0]), xyz(rec[1]), xyz(rec[2]), light)
                    )
                } else {
                    let m: i32 = rec[2..]
                        .iter()
                        .map(|&o| tri_sign(xyz(rec[0]), xyz(rec[1]), xyz(o), light))
                        .sum();
                    format!("{name}: m = {m}")
                }
            })
            .collect();
        out.push(format!("light {light:?}: {}", vals.join("; ")));
    }
    out
}

trait U16x {
    fn u16x(&mut self) -> u16;
}
impl U16x for Cur<'_> {
    fn u16x(&mut self) -> u16 {
        u16::from_le_bytes(self.take(2).try_into().unwrap())
    }
}

fn hexdump(b: &[u8]) -> String {
    let mut s = String::new();
    for (i, row) in b.chunks(16).enumerate() {
        let hex: Vec<String> = row.iter().map(|x| format!("{x:02x}")).collect();
        let ascii: String = row
            .iter()
            .map(|&x| {
                if (0x20..0x7f).contains(&x) {
                    x as char
                } else {
                    '.'
                }
            })
            .collect();
        let _ = writeln!(s, "{:08x}: {:<47}  {ascii}", i * 16, hex.join(" "));
    }
    s
}

fn parse_hexdump(text: &str) -> Vec<u8> {
    let mut out = Vec::new();
    for line in text.lines() {
        let Some((addr, rest)) = line.split_once(": ") else {
            continue;
        };
        if addr.len() != 8 || !addr.chars().all(|c| c.is_ascii_hexdigit()) {
            continue;
        }
        assert_eq!(
            usize::from_str_radix(addr, 16).unwrap(),
            out.len(),
            "hex dump offsets out of sequence"
        );
        for h in rest[..47.min(rest.len())].split_whitespace() {
            out.push(u8::from_str_radix(h, 16).unwrap());
        }
    }
    out
}

#[test]
fn spec_test_vector_matches_byte_for_byte() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("quad.svpk");
    common::svpack()
        .arg("build")
        .arg(common::root().join("fixtures/quad.obj"))
        .arg("-o")
        .arg(&out)
        .assert()
        .code(0);
    let bytes = std::fs::read(&out).unwrap();
    let decoded = decode_per_spec(&bytes);

    let spec_path = common::root().join("format-spec/README.md");
    let spec = std::fs::read_to_string(&spec_path).unwrap();
    let (head, rest) = spec.split_once(BEGIN).expect("begin marker");
    let (region, tail) = rest.split_once(END).expect("end marker");
    if std::env::var_os("SVPACK_BLESS").is_some() {
        let new_region = format!(
            "\nFile bytes ({} bytes):\n\n```text\n{}```\n\nDecoded by following §3 field by field:\n\n```text\n{}\n```\n",
            bytes.len(),
            hexdump(&bytes),
            decoded.join("\n")
        );
        std::fs::write(&spec_path, format!("{head}{BEGIN}{new_region}{END}{tail}")).unwrap();
        return;
    }
    let want = parse_hexdump(region);
    assert!(
        !want.is_empty(),
        "spec has no hex dump (run with SVPACK_BLESS=1)"
    );
    assert_eq!(
        want.len(),
        bytes.len(),
        "file length differs from the spec's test vector"
    );
    if let Some(i) = (0..bytes.len()).find(|&i| want[i] != bytes[i]) {
        panic!(
            "byte {i} (0x{i:x}) is {:02x}, spec says {:02x}",
            bytes[i], want[i]
        );
    }
    for line in &decoded {
        assert!(
            region.contains(line.as_str()),
            "spec lacks decoded line `{line}`"
        );
    }
    // The library reader agrees with the spec-following decoder.
    let f = svpack::format::read_file(&out).unwrap();
    assert!(decoded.contains(&format!("payload_offset = {}", f.header.payload_offset)));
    assert!(decoded.contains(&format!(
        "meshes[0].stats.edges = {}",
        f.header.meshes[0].stats.edges
    )));
}
