#!/usr/bin/env python3
"""Runs the workspace's test binaries a few at a time (`./dev test`).

`cargo test` runs its test binaries one after another. Most of ours wait on
servers, workers, Chromium or PostgreSQL for much of their time, so on 2 cores
one binary at a time leaves a core idle for half of the run. This builds every
test binary once (`cargo test --workspace --no-run --message-format=json`),
then runs them as cargo would (working directory the package's, CARGO_*
variables set), JOBS at a time, longest first, each binary's output printed
whole when it ends. The doc-tests run as one more job. At the end: every
failed binary, then the ten slowest with their wall and CPU time, and the ten
slowest tests (CI time stays visible: the budget of a clean-clone .ci/run is 35
minutes on 2 cores), and, when `./dev test` built with `--timings`, the ten
crates that took longest to compile.

Per-test times: the test binaries fold many test files each (tests/cli,
tests/serve, server/tests/app, ...), so a binary's time says little about
which test is slow. libtest measures each test with `--report-time`, which is
gated behind `-Z unstable-options`; a test binary accepts that on stable when
RUSTC_BOOTSTRAP is set in its environment (libtest reads it at run time), so
the binaries run with RUSTC_BOOTSTRAP=1 and print `test name ... ok <2.345s>`.
The variable reaches what the tests start (d3il, Python, Chromium), none of
which reads it; no test starts cargo or rustc. D3IL_TEST_TIMES=0 turns it off,
and so does a libtest that refuses it (one binary's --list is tried first).

Exits non-zero when the build or any binary fails; every binary runs either
way (as cargo's --no-fail-fast). Arguments after `--` go to every test binary.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

# Wall seconds of the slowest binaries on a 2-core machine (a clean clone's
# CI run of 2026-12-06, three at a time; a binary folded from several test
# files counts as one), so that they start first; others count as short.
# Only the order depends on these.
KNOWN_SECONDS = {
    "agents_torch": 385,
    "closed_loop": 326,
    "cli": 319,  # tests/cli/: the d3il command line
    "replay_records": 308,
    "robustness_server_shards": 306,
    "robustness": 266,
    "serve": 227,  # tests/serve/: the real d3il serve
    "eval": 200,  # tests/eval/: evaluations end to end
    "demos": 200,
    "bench_smoke": 187,
    "python_client": 156,
    "eval_engine": 151,
    "race_server": 143,
    "robustness_shard": 141,
    "cancel_live": 126,
    "simulator": 94,  # evaluator/tests/simulator/: the tasks in MuJoCo
    "sequential_race": 84,
    "chromium": 79,  # tests/chromium/
    "agents_cli": 69,
    "container_image": 64,
    "app": 58,  # server/tests/app/: the server in-process
    "shard": 41,  # tests/shard/
}


@dataclass
class Binary:
    name: str  # what cargo prints after "Running": tests/x.rs, or "<crate> (unit tests)"
    key: str  # the target's name
    executable: str
    cwd: str
    env: dict[str, str]
    wall: float = 0.0
    cpu: float = 0.0
    status: int = 0
    output: str = ""
    argv: list[str] = field(default_factory=list)
    tests: list[tuple[float, str]] = field(default_factory=list)  # (seconds, test name)


# libtest's line for a finished test under --report-time.
TEST_TIME = re.compile(r"^test (\S+) \.\.\. .*<([0-9.]+)s>\s*$", re.MULTILINE)
REPORT_TIME = os.environ.get("D3IL_TEST_TIMES", "1") != "0"
TIMING_ARGS = ["-Z", "unstable-options", "--report-time"]


def timing_works(b: Binary) -> bool:
    """Whether this toolchain's libtest still takes --report-time under
    RUSTC_BOOTSTRAP (a listing, no test runs); if not, the pool runs without."""
    env = {**os.environ, **b.env, "RUSTC_BOOTSTRAP": "1"}
    probe = subprocess.run(
        [b.executable, *TIMING_ARGS, "--list"], cwd=b.cwd, env=env, capture_output=True, check=False
    )
    return probe.returncode == 0


def build(cargo_args: list[str]) -> tuple[list[Binary], Path]:
    """The test binaries of the workspace, built, and cargo's target directory
    (CARGO_TARGET_DIR or the configured one, as cargo metadata reports it)."""
    meta = json.loads(
        subprocess.run(
            ["cargo", "metadata", "--format-version=1", "--no-deps"], check=True, capture_output=True, text=True
        ).stdout
    )
    packages: dict[str, dict] = {p["id"]: p for p in meta["packages"]}
    cmd = ["cargo", "test", "--workspace", "--no-run", "--message-format=json-render-diagnostics", *cargo_args]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    bins: list[Binary] = []
    assert proc.stdout is not None
    for line in proc.stdout:
        try:
            msg = json.loads(line)
        except json.JSONDecodeError:
            continue
        if msg.get("reason") != "compiler-artifact" or not msg.get("executable") or not msg["profile"]["test"]:
            continue
        target = msg["target"]
        pkg = packages.get(msg["package_id"])
        if pkg is None:
            continue
        manifest_dir = str(Path(pkg["manifest_path"]).parent)
        src = Path(target["src_path"])
        if "test" in target["kind"]:
            try:
                name = str(src.relative_to(manifest_dir))
            except ValueError:
                name = str(src)
        else:
            name = f"{target['name']} (unit tests)"
        env = {
            "CARGO_MANIFEST_DIR": manifest_dir,
            "CARGO_PKG_NAME": pkg["name"],
            "CARGO_PKG_VERSION": pkg["version"],
            "CARGO_CRATE_NAME": target["name"].replace("-", "_"),
        }
        bins.append(Binary(name=name, key=target["name"], executable=msg["executable"], cwd=manifest_dir, env=env))
    if proc.wait() != 0:
        sys.exit(f"test_pool: `{' '.join(cmd)}` failed (exit {proc.returncode}): the build errors are above")
    return bins, Path(meta["target_directory"])


def run(b: Binary, test_args: list[str], lock: threading.Lock) -> None:
    env = dict(os.environ)
    env.update(b.env)
    deps = str(Path(b.executable).parent)
    env["LD_LIBRARY_PATH"] = deps + (":" + env["LD_LIBRARY_PATH"] if env.get("LD_LIBRARY_PATH") else "")
    b.argv = [b.executable, *test_args]
    if REPORT_TIME:
        env["RUSTC_BOOTSTRAP"] = "1"
        b.argv += TIMING_ARGS
    with tempfile.TemporaryFile(mode="w+") as out:
        t0 = time.monotonic()
        proc = subprocess.Popen(b.argv, cwd=b.cwd, env=env, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        b.wall = time.monotonic() - t0
        b.cpu = usage.ru_utime + usage.ru_stime
        b.status = proc.returncode
        out.seek(0)
        b.output = out.read()
    b.tests = [(float(s), name) for name, s in TEST_TIME.findall(b.output)]
    with lock:
        print(f"     Running {b.name} ({b.executable})", flush=True)
        sys.stdout.write(b.output)
        verdict = "ok" if b.status == 0 else f"FAILED (exit {b.status})"
        print(f"  {b.name}: {verdict} in {b.wall:.1f} s wall, {b.cpu:.1f} s CPU\n", flush=True)


def main() -> int:
    args = sys.argv[1:]
    jobs = int(os.environ.get("D3IL_TEST_JOBS", "3"))
    if "--" in args:
        i = args.index("--")
        cargo_args, test_args = args[:i], args[i + 1 :]
    else:
        cargo_args, test_args = args, []
    cargo_args = [a for a in cargo_args if a != "--no-fail-fast"]
    # When `./dev test` started its build (with --timings): a timings report
    # older than that is another build's.
    t_start = float(os.environ.get("D3IL_BUILD_STARTED", time.time()))
    t_build = time.monotonic()
    bins, target_dir = build(cargo_args)
    global REPORT_TIME
    if REPORT_TIME and bins and not timing_works(bins[0]):
        print("test_pool: this libtest refuses --report-time; no per-test times", flush=True)
        REPORT_TIME = False
    print(f"test_pool: {len(bins)} test binaries built in {time.monotonic() - t_build:.0f} s; running {jobs} at a time", flush=True)
    doc = Binary(
        name="doc-tests",
        key="doc-tests",
        executable="cargo",
        cwd=os.getcwd(),
        env={},
    )
    queue = sorted(bins, key=lambda b: -KNOWN_SECONDS.get(b.key, 0))
    lock = threading.Lock()
    t0 = time.monotonic()

    def worker() -> None:
        while True:
            with lock:
                if not queue:
                    return
                b = queue.pop(0)
            run(b, test_args, lock)

    threads = [threading.Thread(target=worker) for _ in range(max(1, jobs))]
    for t in threads:
        t.start()
    # The doc-tests (rustdoc compiles each) run beside the binaries.
    d0 = time.monotonic()
    doc_proc = subprocess.run(
        ["cargo", "test", "--workspace", "--doc", *cargo_args, "--", *test_args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    doc.wall = time.monotonic() - d0
    doc.status = doc_proc.returncode
    with lock:
        print("     Doc-tests (cargo test --workspace --doc)")
        sys.stdout.write(doc_proc.stdout)
    for t in threads:
        t.join()
    wall = time.monotonic() - t0
    everything = [*bins, doc]
    failed = [b for b in everything if b.status != 0]
    print(f"\ntest_pool: {len(everything)} test binaries in {wall:.0f} s wall, {sum(b.cpu for b in bins):.0f} s CPU")
    if failed:
        print(f"{len(failed)} failed:")
        for b in failed:
            again = " ".join(b.argv) if b.argv else "cargo test --workspace --doc"
            if b.argv and REPORT_TIME:
                again = f"RUSTC_BOOTSTRAP=1 {again}"
            print(f"  {b.name} (exit {b.status}): {again}")
    print("\nslowest test binaries (wall, CPU):")
    for b in sorted(bins, key=lambda b: -b.wall)[:10]:
        print(f"{b.wall:10.1f} s {b.cpu:8.1f} s CPU  {b.name}")
    tests = sorted(((s, b.key, name) for b in bins for s, name in b.tests), reverse=True)
    if tests:
        print("\nslowest tests (wall, binary, test):")
        for s, key, name in tests[:10]:
            print(f"{s:10.1f} s  {key}  {name}")
    slowest_build_units(target_dir / "cargo-timings" / "cargo-timing.html", t_start)
    return 1 if failed else 0


def build_units(html: str) -> list[dict]:
    """The units of a `cargo build --timings` report (its `const UNIT_DATA = [...];`)."""
    start = html.find("const UNIT_DATA = ")
    if start < 0:
        return []
    start = html.index("[", start)
    end = html.index("\n];", start) + 2
    return json.loads(html[start:end])


def slowest_build_units(report: Path, since: float) -> None:
    """The ten units that took longest to compile in the build this run made
    (`./dev test` builds with `--timings`), so that build time is as visible as
    test time; nothing when the report is older than this run (nothing was
    rebuilt) or missing."""
    try:
        if not report.exists() or report.stat().st_mtime < since:
            return
        units = build_units(report.read_text())
        if not units:
            return
        total = sum(u["duration"] for u in units)
        span = max(u["start"] + u["duration"] for u in units)
    except (OSError, ValueError, KeyError) as e:
        # Another cargo's report format: the tests' verdict does not depend on it.
        print(f"\ntest_pool: no build timings ({report}: {e!r})")
        return
    print(f"\nslowest build units ({len(units)} units, {total:.0f} s of compiling in {span:.0f} s; {report}):")
    for u in sorted(units, key=lambda u: -u["duration"])[:10]:
        print(f"{u['duration']:10.1f} s  {u['name']} {u['version']}{u['target']}")


if __name__ == "__main__":
    sys.exit(main())
