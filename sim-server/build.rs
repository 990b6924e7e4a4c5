//! One cfg for the allocator choice, so that the code says `jemalloc_allocator` once instead of
//! repeating the feature logic: jemalloc is the global allocator when the `jemalloc` feature is
//! on (the default) and the `glibc` feature does not ask for glibc malloc instead.

fn main() {
    println!("cargo::rustc-check-cfg=cfg(jemalloc_allocator)");
    let jemalloc = std::env::var_os("CARGO_FEATURE_JEMALLOC").is_some();
    let glibc = std::env::var_os("CARGO_FEATURE_GLIBC").is_some();
    if jemalloc && !glibc {
        println!("cargo::rustc-cfg=jemalloc_allocator");
    }
}
