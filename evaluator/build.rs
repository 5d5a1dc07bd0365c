//! Links libmujoco 2.2 and fails with an actionable message when it is missing.
use std::path::Path;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed=MUJOCO_LIB_DIR");
    let lib_dir =
        std::env::var("MUJOCO_LIB_DIR").unwrap_or_else(|_| "/usr/lib/x86_64-linux-gnu".into());
    let header = Path::new("/usr/include/mujoco/mujoco.h");
    let lib = Path::new(&lib_dir).join("libmujoco.so");
    if !lib.exists() || !header.exists() {
        panic!(
            "\n\nlibmujoco 2.2 was not found ({} / {}).\n\
             Install it with:  sudo apt-get install -y libmujoco-dev\n\
             (Debian bookworm ships MuJoCo 2.2.2; set MUJOCO_LIB_DIR if it lives elsewhere.)\n\n",
            lib.display(),
            header.display()
        );
    }
    let version = std::fs::read_to_string(header).unwrap_or_default();
    if !version.contains("#define mjVERSION_HEADER 222") {
        panic!("\n\n/usr/include/mujoco/mujoco.h is not MuJoCo 2.2.2 (mjVERSION_HEADER 222 expected).\nInstall Debian's libmujoco-dev 2.2.2: sudo apt-get install -y libmujoco-dev\n\n");
    }
    embed_panda_meshes();
    println!("cargo:rustc-link-search=native={lib_dir}");
    println!("cargo:rustc-link-lib=dylib=mujoco");
    #[cfg(feature = "regenerate-bindings")]
    regenerate();
}

/// The Panda meshes that `./dev` converts from the `example-robot-data`
/// package into assets/meshes/ (scripts/panda_meshes.py) are compiled into the
/// binary, every `panda_*.obj` there as (file name, contents), so that
/// sandboxed workers need no file access for them; the scene checks that the
/// ones it needs are present (`scene::meshes_available`), else it keeps
/// primitive shapes.
fn embed_panda_meshes() {
    let manifest = std::env::var("CARGO_MANIFEST_DIR").expect("set by cargo");
    let dir = Path::new(&manifest).join("../assets/meshes");
    // A directory's mtime changes when files are added or replaced in it.
    if dir.is_dir() {
        println!("cargo:rerun-if-changed={}", dir.display());
    } else {
        println!(
            "cargo:rerun-if-changed={}",
            Path::new(&manifest).join("../assets").display()
        );
    }
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            p.is_file() && name.starts_with("panda_") && name.ends_with(".obj")
        })
        .collect();
    files.sort();
    let mut code = String::from(
        "/// (file name, OBJ) of the Panda meshes converted from example-robot-data at\n\
         /// set-up time (none when ./dev has not converted them).\n\
         pub const PANDA_MESHES: &[(&str, &str)] = &[\n",
    );
    for p in &files {
        println!("cargo:rerun-if-changed={}", p.display());
        let abs = p.canonicalize().expect("exists").display().to_string();
        let name = p.file_name().expect("a file").to_string_lossy().to_string();
        code.push_str(&format!("    ({name:?}, include_str!({abs:?})),\n"));
    }
    code.push_str("];\n");
    let out = Path::new(&std::env::var("OUT_DIR").expect("set by cargo")).join("panda_meshes.rs");
    std::fs::write(out, code).expect("writing OUT_DIR/panda_meshes.rs");
}

#[cfg(feature = "regenerate-bindings")]
fn regenerate() {
    let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/mujoco/bindings.rs");
    bindgen::Builder::default()
        .header("/usr/include/mujoco/mujoco.h")
        .clang_arg("-I/usr/include/mujoco")
        .allowlist_function("mj.*")
        .allowlist_type("mj.*")
        .allowlist_var("mj.*")
        .layout_tests(false)
        .derive_default(true)
        .generate()
        .expect("bindgen failed on mujoco.h")
        .write_to_file(&out)
        .expect("writing bindings.rs");
}
