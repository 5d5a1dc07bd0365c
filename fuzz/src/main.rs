//! `d3il-fuzz <target>`: one afl.rs binary for every fuzz target
//! (`d3il_fuzz_targets::TARGETS`); the target's name is the first argument,
//! so one instrumented build serves them all. Run it through scripts/fuzz.

use std::sync::Once;

fn main() {
    let name = std::env::args().nth(1).unwrap_or_default();
    let Some(target) = d3il_fuzz_targets::target(&name) else {
        let names: Vec<&str> = d3il_fuzz_targets::TARGETS.iter().map(|t| t.name).collect();
        eprintln!("usage: d3il-fuzz <target>; targets: {}", names.join(", "));
        std::process::exit(2);
    };
    let run = target.run;
    // ONNX admission runs confined as in the worker. The fork server's
    // children start single-threaded; each confines itself before its first run.
    let confine = name == "onnx_admit";
    static CONFINED: Once = Once::new();
    // Without afl.rs's panic hook: production catches some panics itself
    // (tract's, in `OnnxPolicy::load`), so only a panic that escapes the
    // harness aborts.
    afl::fuzz_nohook!(|data: &[u8]| {
        if confine {
            CONFINED.call_once(|| match d3il_fuzz_targets::confine_like_worker() {
                Ok(mechanisms) => {
                    for m in mechanisms {
                        eprintln!("sandbox: {} {} {}", m.name, m.active, m.detail);
                    }
                }
                Err(e) => panic!("cannot confine like the worker: {e}"),
            });
        }
        run(data);
    });
}
