// The schema migrations (migrations/sqlite, migrations/postgres) embedded in
// the binary: `$OUT_DIR/migrations.rs` lists each backend's files as
// (version, description, SQL), read by `store::MIGRATOR` and `MIGRATOR_PG`.
// The names follow sqlx's migration rule, `<version>_<description>.sql`, and
// the description is the name's rest with `_` read as a space, so that a
// database migrated by an earlier build (which embedded them with
// `sqlx::migrate!`) records the same versions, descriptions and checksums.
// Done here rather than with that macro: the macro crate compiles both
// database drivers, bundled SQLite included, a second time for the host
// (about a minute of every clean build).
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

fn migrations(dir: &Path) -> Vec<(i64, String, PathBuf)> {
    println!("cargo:rerun-if-changed={}", dir.display());
    let mut out = Vec::new();
    let entries = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("cannot read the migrations in {}: {e}", dir.display()));
    for entry in entries {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let Some(stem) = name.strip_suffix(".sql") else {
            continue;
        };
        let Some((version, description)) = stem.split_once('_') else {
            panic!("migration {name}: expected <version>_<description>.sql");
        };
        let version: i64 = version.parse().unwrap_or_else(|_| {
            panic!("migration {name}: the version before `_` is not an integer")
        });
        println!("cargo:rerun-if-changed={}", path.display());
        out.push((version, description.replace('_', " "), path));
    }
    out.sort();
    out
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../migrations");
    let mut code = String::new();
    for (constant, backend) in [
        ("SQLITE_MIGRATIONS", "sqlite"),
        ("POSTGRES_MIGRATIONS", "postgres"),
    ] {
        writeln!(
            code,
            "pub(crate) const {constant}: &[(i64, &str, &str)] = &["
        )
        .unwrap();
        for (version, description, path) in migrations(&root.join(backend)) {
            let path = path.canonicalize().unwrap();
            writeln!(
                code,
                "    ({version}, {description:?}, include_str!({:?})),",
                path.display().to_string()
            )
            .unwrap();
        }
        writeln!(code, "];").unwrap();
    }
    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap()).join("migrations.rs");
    std::fs::write(out, code).unwrap();
}
