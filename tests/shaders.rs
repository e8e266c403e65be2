//! The reference GLSL ES 1.00 shaders in format-spec/shaders compile for every
//! bucket size, and use the operation order of src/multiplicity.rs.
//!
//! Needs `glslangValidator` (Debian package glslang-tools; .ci/run installs
//! it). Without it the compile check is skipped with a message, unless
//! SVPACK_REQUIRE_GLSLANG is set (CI sets it), in which case it fails.

mod common;

use std::process::Command;

fn shader(name: &str) -> String {
    std::fs::read_to_string(common::root().join("format-spec/shaders").join(name)).unwrap()
}

fn validate(src: &str, label: &str) -> Result<(), String> {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join(format!("{label}.vert"));
    std::fs::write(&p, src).unwrap();
    let out = Command::new("glslangValidator")
        .arg(&p)
        .output()
        .map_err(|e| e.to_string())?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "{label}: {}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ))
    }
}

fn sources() -> Vec<(String, String)> {
    let common = shader("common.glsl");
    let mut v = Vec::new();
    for k in 1..=13 {
        v.push((
            format!("sides_k{k}"),
            format!(
                "#version 100\n#define SVPK_K {k}\nprecision highp float;\n{common}{}",
                shader("sides.vert")
            ),
        ));
    }
    v.push((
        "caps".into(),
        format!(
            "#version 100\nprecision highp float;\n{common}{}",
            shader("caps.vert")
        ),
    ));
    v
}

#[test]
fn reference_shaders_compile_as_glsl_es_100() {
    if Command::new("glslangValidator")
        .arg("--version")
        .output()
        .is_err()
    {
        assert!(
            std::env::var_os("SVPACK_REQUIRE_GLSLANG").is_none(),
            "glslangValidator is required (apt-get install glslang-tools)"
        );
        eprintln!("skipping: glslangValidator not installed (apt-get install glslang-tools)");
        return;
    }
    for (label, src) in sources() {
        validate(&src, &label).unwrap();
    }
    // The check can fail: a sides shader for K = 14 would need aO13, which
    // the reference does not declare... but it also must not silently accept
    // broken GLSL: feed it a syntax error.
    let broken = sources()[0].1.replace("float m = ", "float m == ");
    assert!(
        validate(&broken, "broken").is_err(),
        "validator accepted a broken shader"
    );
}

/// The GLSL reference expression is the spec's, operation for operation (a
/// textual check: the same lines as src/multiplicity.rs, in the same order).
#[test]
fn glsl_and_rust_use_the_same_operation_order() {
    let glsl = shader("common.glsl");
    let rust = std::fs::read_to_string(common::root().join("src/multiplicity.rs")).unwrap();
    let norm = |s: &str| s.chars().filter(|c| !c.is_whitespace()).collect::<String>();
    let glsl_n = norm(&glsl);
    let rust_n = norm(&rust);
    // (GLSL spelling, Rust spelling) of each operation, in order.
    let ops = [
        ("vec3x=r2-r0;", "letx0=r2[0]-r0[0];"),
        ("L.x-r0.x*L.w", "l[0]-r0[0]*l[3]"),
        ("L.y-r0.y*L.w", "l[1]-r0[1]*l[3]"),
        ("L.z-r0.z*L.w", "l[2]-r0[2]*l[3]"),
        ("vec3d=r1-r0;", "letd0=r1[0]-r0[0];"),
        ("floatnx=x.y*y.z-x.z*y.y;", "letn0=x1*y2-x2*y1;"),
        ("floatny=x.z*y.x-x.x*y.z;", "letn1=x2*y0-x0*y2;"),
        ("floatnz=x.x*y.y-x.y*y.x;", "letn2=x0*y1-x1*y0;"),
        ("floats=(nx*d.x+ny*d.y)+nz*d.z;", "(n0*d0+n1*d1)+n2*d2"),
    ];
    let (mut gi, mut ri) = (0, 0);
    for (g, r) in ops {
        gi = gi
            + glsl_n[gi..]
                .find(g)
                .unwrap_or_else(|| panic!("GLSL lacks `{g}` in order"));
        ri = ri
            + rust_n[ri..]
                .find(r)
                .unwrap_or_else(|| panic!("Rust lacks `{r}` in order"));
    }
    assert!(
        !glsl_n.contains("cross(") && !glsl_n.contains("dot("),
        "use explicit operations, not cross()/dot()"
    );
}
