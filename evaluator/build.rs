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
    println!("cargo:rustc-link-search=native={lib_dir}");
    println!("cargo:rustc-link-lib=dylib=mujoco");
    #[cfg(feature = "regenerate-bindings")]
    regenerate();
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
