//! Test-only hostile worker: `d3il-sandbox-selftest <mode> [--require all]`.
//! Runs the real worker flow (stdin job, confinement, JSON lines, exit codes)
//! with a misbehaving "evaluation" from `d3il_sandbox::selftest`.

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mode = args.first().cloned().unwrap_or_default();
    let mut opts = d3il_sandbox::WorkerOptions::default();
    if let Some(i) = args.iter().position(|a| a == "--require") {
        if let Some(r) = args.get(i + 1) {
            opts.require = r.split(',').map(str::to_string).collect();
        }
    }
    if mode == "check-sandbox" {
        // What `d3il worker --check-sandbox` does, as JSON.
        let assets = args.get(1).map(String::as_str).unwrap_or("assets");
        match d3il_sandbox::check_sandbox(std::path::Path::new(assets)) {
            Ok(m) => {
                println!("{}", serde_json::to_string(&m).unwrap_or_default());
                std::process::exit(0);
            }
            Err(e) => {
                eprintln!("{e}");
                std::process::exit(d3il_protocol::exit_code::SANDBOX_FAILED);
            }
        }
    }
    if let Some(code) = d3il_sandbox::selftest::before_worker(&mode) {
        std::process::exit(code);
    }
    let code = d3il_sandbox::worker_main(&opts, |job, progress| {
        let mut counts =
            |done: usize, total: usize| progress(&d3il_protocol::Progress::counts(done, total));
        d3il_sandbox::selftest::evaluate(&mode, job, &mut counts).map(Into::into)
    });
    std::process::exit(code);
}
