//! Links Embree 3 when the `embree` feature is on and the library is installed (Debian's
//! libembree-dev 3.13, `scripts/setup.sh`); otherwise the embree-* methods report, at planning,
//! how to enable them. A missing library is not a build error: the README's two commands must work
//! on a fresh machine.
use std::path::Path;

fn main() {
    println!("cargo:rustc-check-cfg=cfg(has_embree)");
    println!("cargo:rerun-if-env-changed=EMBREE_DIR");
    if std::env::var_os("CARGO_FEATURE_EMBREE").is_none() {
        return;
    }
    let dirs: Vec<String> = match std::env::var("EMBREE_DIR") {
        Ok(d) => vec![format!("{d}/lib"), format!("{d}/lib64")],
        Err(_) => ["/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib", "/usr/local/lib"]
            .iter()
            .map(|s| s.to_string())
            .collect(),
    };
    // The development symlink comes with libembree-dev (as do the headers the C API follows).
    match dirs.iter().find(|d| Path::new(&format!("{d}/libembree3.so")).exists()) {
        Some(d) => {
            // An upgrade or removal of the library reruns this script.
            println!("cargo:rerun-if-changed={d}/libembree3.so");
            println!("cargo:rustc-link-search=native={d}");
            println!("cargo:rustc-link-lib=dylib=embree3");
            println!("cargo:rustc-cfg=has_embree");
        }
        None => {
            println!(
                "cargo:warning=Embree 3 not found (libembree3.so): the embree-* methods are disabled; run scripts/setup.sh (installs libembree-dev) and rebuild"
            );
            // Notice a later installation. Its files keep the package's old mtimes, so
            // `rerun-if-changed` on them does not (seen: Embree stayed disabled after
            // scripts/setup.sh until `cargo clean`); the package database changes on every
            // installation, so it is the file to watch where there is one. Elsewhere a path that
            // never exists keeps this script stale (rerun, and this crate rebuilt, on every build
            // until Embree is found; EMBREE_DIR changes rerun it too).
            let dpkg = Path::new("/var/lib/dpkg/status");
            if dpkg.exists() {
                println!("cargo:rerun-if-changed={}", dpkg.display());
            } else if let Some(out) = std::env::var_os("OUT_DIR") {
                println!("cargo:rerun-if-changed={}", Path::new(&out).join("embree-not-found").display());
            }
        }
    }
}
