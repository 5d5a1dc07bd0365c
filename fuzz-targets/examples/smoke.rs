//! A quick, uninstrumented mutation pass over the seeds (no coverage
//! feedback): finds the shallow crashes in seconds, before the long afl
//! runs. Not a substitute for scripts/fuzz.
//!
//! ```text
//! cargo run -p d3il-fuzz-targets --example smoke -- <target|all> [runs per target] [out dir]
//! ```

use std::path::{Path, PathBuf};

/// Tokens that tend to break parsers of numbers and structures.
const TOKENS: &[&[u8]] = &[
    b"18446744073709551615",
    b"9223372036854775807",
    b"-1",
    b"1e400",
    b"-0",
    b"NaN",
    b"null",
    b"[]",
    b"{}",
    b"\"\"",
    b"4294967296",
    b"0",
    b"%00",
    b"%ff",
    b"&page=",
    b"&per_page=",
];

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next() % n as u64) as usize
        }
    }
}

fn mutate(rng: &mut Rng, seed: &[u8]) -> Vec<u8> {
    let mut v = seed.to_vec();
    for _ in 0..1 + rng.below(4) {
        let at = rng.below(v.len() + 1);
        match rng.below(5) {
            0 if !v.is_empty() => {
                let i = rng.below(v.len());
                v[i] ^= 1 << rng.below(8);
            }
            1 if !v.is_empty() => {
                let end = (at + 1 + rng.below(16)).min(v.len());
                v.drain(at.min(end)..end);
            }
            2 => {
                // Replace a run of digits (or insert) with a token.
                let t = TOKENS[rng.below(TOKENS.len())];
                let mut end = at;
                while end < v.len() && (v[end].is_ascii_digit() || v[end] == b'.') {
                    end += 1;
                }
                v.splice(at..end, t.iter().copied());
            }
            3 if !v.is_empty() => {
                let i = rng.below(v.len());
                v[i] = rng.next() as u8;
            }
            _ => v.insert(at, rng.next() as u8),
        }
    }
    v
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let which = args.get(1).cloned().unwrap_or_else(|| "all".into());
    let runs: usize = args.get(2).and_then(|n| n.parse().ok()).unwrap_or(2000);
    let out = PathBuf::from(
        args.get(3)
            .cloned()
            .unwrap_or_else(|| "/tmp/d3il-smoke".into()),
    );
    let seeds_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/seeds");
    std::panic::set_hook(Box::new(|_| {}));
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    for t in d3il_fuzz_targets::TARGETS {
        if which != "all" && which != t.name {
            continue;
        }
        let seeds: Vec<Vec<u8>> = std::fs::read_dir(seeds_dir.join(t.name))
            .into_iter()
            .flatten()
            .flatten()
            .filter_map(|e| std::fs::read(e.path()).ok())
            .collect();
        let mut found = 0;
        for i in 0..runs {
            let pick = rng.below(seeds.len());
            let input = mutate(&mut rng, &seeds[pick]);
            let outcome = std::panic::catch_unwind(|| (t.run)(&input));
            if let Err(p) = outcome {
                found += 1;
                let msg = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                let dir = out.join(t.name);
                std::fs::create_dir_all(&dir).expect("out dir");
                let file = dir.join(format!("crash-{i}"));
                std::fs::write(&file, &input).expect("write");
                println!(
                    "{}: {} -> {}",
                    t.name,
                    file.display(),
                    msg.chars().take(300).collect::<String>()
                );
            }
        }
        println!("{}: {runs} runs, {found} findings", t.name);
    }
}
