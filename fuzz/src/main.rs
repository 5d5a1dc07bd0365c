//! `d3il-fuzz <target>`: one afl.rs binary for every fuzz target
//! (`d3il_fuzz_targets::TARGETS`); the target's name is the first argument,
//! so one instrumented build serves them all. Run it through scripts/fuzz.

fn main() {
    let name = std::env::args().nth(1).unwrap_or_default();
    let Some(target) = d3il_fuzz_targets::target(&name) else {
        let names: Vec<&str> = d3il_fuzz_targets::TARGETS.iter().map(|t| t.name).collect();
        eprintln!("usage: d3il-fuzz <target>; targets: {}", names.join(", "));
        std::process::exit(2);
    };
    if name == "onnx_admit" {
        if let Err(e) = d3il_fuzz_targets::apply_worker_limits() {
            eprintln!("cannot apply the worker's address-space limit: {e}");
            std::process::exit(1);
        }
    }
    let run = target.run;
    // Without afl.rs's panic hook: production catches some panics itself (tract's, in
    // `OnnxPolicy::load`), so only a panic that escapes the harness aborts.
    afl::fuzz_nohook!(|data: &[u8]| {
        run(data);
    });
}
