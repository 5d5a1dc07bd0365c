r"""``d3il-client``: the API client on the command line, for shell scripts and Slurm jobs.

    d3il-client submit --server URL --token T --method NAME --task aligning \\
        --training-seed 0 --onnx policy.onnx --wait
    d3il-client status ID
    d3il-client results ID [--json] [--rollouts-csv r.csv]
    d3il-client compare A B [--json]
    d3il-client leaderboard aligning [--obs state] [--csv out.csv] [--json]
    d3il-client export --agent my_module:make_agent --checkpoint ckpt.pth --task aligning --out policy.onnx

``submit`` takes the flags of ``d3il submit`` and prints what it prints:
``submission N accepted: URL``, with ``--wait`` progress lines on standard
error, then the metrics table of ``d3il eval`` (``--json``: the server's
document). Every command reads ``--server`` from ``$D3IL_SERVER`` and
``--token`` from ``$D3IL_TOKEN`` when not given. Exit status 1 on any error,
with the server's message.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any, List, Optional

from . import errors
from ._version import __version__
from .client import Client, progress_line
from .models import Submission
from .text import comparison_table, leaderboard_table, metrics_table


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="d3il-client",
        description="Submit policies to a D3IL leaderboard, follow them, fetch and compare results.",
    )
    ap.add_argument("--version", action="version", version=f"d3il-client {__version__}")
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--server", help="server root URL (default $D3IL_SERVER, else http://127.0.0.1:8080)")
    common.add_argument("--token", help="API token (default $D3IL_TOKEN); needed to submit")
    sub = ap.add_subparsers(dest="command", required=True)

    s = sub.add_parser("submit", parents=[common], help="submit a policy (the flags of `d3il submit`)")
    s.add_argument("--method", required=True, help="method name")
    s.add_argument("--task", required=True, help="task slug (avoiding, aligning, pushing, sorting-2/4/6, ...)")
    s.add_argument("--obs-type", default="state", help="state or image (must match the manifest)")
    s.add_argument("--training-seed", type=int, required=True, help="training seed of this policy (0, 1, ...)")
    s.add_argument("--data-fraction", type=float, default=1.0, help="fraction of the demonstrations (0 < f <= 1)")
    s.add_argument("--protocol", default="paper", help="paper (full protocol) or quick (smoke test)")
    s.add_argument("--suite", help="robustness: evaluate the task's perturbation suite too (docs/robustness.md)")
    what = s.add_mutually_exclusive_group(required=True)
    what.add_argument("--onnx", help="ONNX policy file (its manifest next to it as FILE.json, or --manifest)")
    what.add_argument(
        "--endpoint",
        help="remote policy endpoint URL (ws://, wss://); with $D3IL_ENDPOINT_SECRET set, the evaluator "
        "sends that shared secret to it (docs/remote-protocol.md)",
    )
    s.add_argument("--manifest", help="policy manifest JSON file for --onnx")
    s.add_argument("--history", type=int, help="method metadata: observation history length k")
    s.add_argument("--backbone", help="method metadata: network backbone (MLP, GPT, ...)")
    s.add_argument("--prediction", help="method metadata: single action, action chunk, ...")
    s.add_argument("--diversity", help="method metadata: where its diversity comes from")
    s.add_argument("--code-url", help="method metadata: URL of the method's code")
    s.add_argument("--paper-url", help="method metadata: URL of the method's paper")
    s.add_argument("--description", help="one-paragraph description of the method")
    s.add_argument("--wait", action="store_true", help="wait for the evaluation and print its metrics table")
    s.add_argument("--json", action="store_true", help="with --wait: print the server's document instead")
    s.add_argument("--timeout", type=float, default=7200, help="give up waiting after this many seconds")

    st = sub.add_parser("status", parents=[common], help="a submission's status and progress")
    st.add_argument("id", type=int)
    st.add_argument("--json", action="store_true", help="print the server's document")

    r = sub.add_parser("results", parents=[common], help="a completed submission's metrics table")
    r.add_argument("id", type=int)
    r.add_argument("--json", action="store_true", help="print the server's results document")
    r.add_argument("--rollouts-csv", metavar="FILE", help="also write the per-rollout table as CSV")
    r.add_argument("--contexts-csv", metavar="FILE", help="also write the per-initial-state table as CSV")

    c = sub.add_parser("compare", parents=[common], help="paired comparison A − B of two submissions")
    c.add_argument("a", type=int)
    c.add_argument("b", type=int)
    c.add_argument("--json", action="store_true", help="print the server's document")

    ex = sub.add_parser(
        "export",
        help="export a D3IL reference agent to ONNX, checked against its predict() (docs/export.md; needs torch)",
    )
    ex.add_argument("--agent", required=True, metavar="MODULE:NAME", help="factory of the trained agent object")
    ex.add_argument("--checkpoint", help="passed to MODULE:NAME as its one argument")
    ex.add_argument("--task", required=True, help="task slug (aligning, pushing, ...)")
    ex.add_argument("--out", default="policy.onnx", help="ONNX file to write; its manifest goes next to it as .json")
    ex.add_argument("--d3il", help="d3il binary for the runtime check (default $D3IL_BIN, else d3il on the PATH)")
    ex.add_argument("--atol", type=float, default=1e-5, help="largest action difference the checks accept")

    lb = sub.add_parser("leaderboard", parents=[common], help="a task's leaderboard")
    lb.add_argument("task")
    lb.add_argument("--obs", default="state", help="state or image")
    lb.add_argument("--view", default="main", help="main or data-fraction")
    lb.add_argument("--json", action="store_true", help="print the server's document")
    lb.add_argument("--csv", metavar="FILE", help="save the server's CSV to FILE instead of printing a table")
    return ap


def _print_json(doc: Any) -> None:
    print(json.dumps(doc, indent=2))


def _submit(client: Client, a: argparse.Namespace) -> int:
    if not client.token:
        raise errors.D3ILError("give --token or set D3IL_TOKEN (mint one with `d3il token create --name <you>`)")
    sub = client.submit(
        method=a.method,
        task=a.task,
        training_seed=a.training_seed,
        onnx=a.onnx,
        manifest=a.manifest,
        endpoint=a.endpoint,
        endpoint_secret=(os.environ.get("D3IL_ENDPOINT_SECRET") or None) if a.endpoint else None,
        obs_type=a.obs_type,
        data_fraction=a.data_fraction,
        protocol=a.protocol,
        history=a.history,
        backbone=a.backbone,
        prediction=a.prediction,
        diversity=a.diversity,
        code_url=a.code_url,
        paper_url=a.paper_url,
        description=a.description,
        suite=a.suite,
        progress=sys.stderr.isatty(),
    )
    print(f"submission {sub.id} accepted: {client.server}{sub.url}", flush=True)
    quota = sub.raw.get("quota")
    if isinstance(quota, dict) and isinstance(quota.get("summary"), str):
        # as `d3il submit`: what is left of the quota, after the accepted line
        print(f"quota: {quota['summary']}", file=sys.stderr, flush=True)
    if not a.wait:
        return 0
    last = [""]

    def show(s: Submission) -> None:
        line = progress_line(s)
        if line != last[0]:
            print(line, file=sys.stderr, flush=True)
            last[0] = line

    # A bar on a terminal; plain lines (as `d3il submit --wait`) in logs.
    tty = sys.stderr.isatty()
    try:
        done = client.wait(sub, timeout=a.timeout, progress=tty, on_update=None if tty else show)
    except errors.EvaluationFailed as e:
        if a.json:
            _print_json(e.submission.raw)
        raise
    if a.json:
        _print_json(done.raw)
    else:
        assert done.result is not None
        print(metrics_table(done.result, client.rollouts(done)), end="")
    return 0


def _status(client: Client, a: argparse.Namespace) -> int:
    sub = client.submission(a.id)
    if a.json:
        _print_json(sub.raw)
        return 0
    print(
        f"submission {sub.id}: {sub.method}, {sub.task} ({sub.obs_type}), training seed {sub.training_seed}, "
        f"{sub.protocol} protocol"
    )
    print(progress_line(sub))
    if sub.error is not None:
        print(f"error ({sub.error.kind}): {sub.error.message or ''}")
    print(f"{client.server}{sub.url}")
    return 1 if sub.status == "failed" else 0


def _results(client: Client, a: argparse.Namespace) -> int:
    res = client.results(a.id)
    if a.json:
        _print_json(res.raw)
    else:
        print(metrics_table(res, client.rollouts(a.id)), end="")
    if a.rollouts_csv:
        client.rollouts_frame(a.id).to_csv(a.rollouts_csv, index=False)
    if a.contexts_csv:
        res.contexts_frame().to_csv(a.contexts_csv, index=False)
    return 0


def _compare(client: Client, a: argparse.Namespace) -> int:
    c = client.compare(a.a, a.b)
    if a.json:
        _print_json(c.raw)
    else:
        print(comparison_table(c), end="")
    return 0


def _leaderboard(client: Client, a: argparse.Namespace) -> int:
    if a.csv:
        client.download_csv(a.task, a.csv, a.obs, view=a.view)
        return 0
    board = client.leaderboard(a.task, a.obs, view=a.view)
    if a.json:
        _print_json(board.raw)
    else:
        print(leaderboard_table(board), end="")
    return 0


def _export(a: argparse.Namespace) -> int:
    try:
        from .agents import UnknownAgent
        from .agents.check import CheckFailed
        from .agents.export import ExportFailed, export_agent
    except ImportError as e:
        print(f"error: export needs torch and onnxruntime (pip install 'd3il-client[export]'): {e}", file=sys.stderr)
        return 1
    from .objects import make_agent

    agent = make_agent(a.agent, a.checkpoint)
    try:
        report = export_agent(agent, a.task, a.out, atol=a.atol, d3il=a.d3il)
    except (UnknownAgent, CheckFailed, ExportFailed) as e:
        print(f"error: {e}\nnothing was written", file=sys.stderr)
        return 1
    print(report.summary())
    return 0


COMMANDS = {
    "submit": _submit,
    "status": _status,
    "results": _results,
    "compare": _compare,
    "leaderboard": _leaderboard,
}


def main(argv: Optional[List[str]] = None) -> int:
    """Run ``d3il-client`` with ``argv`` (default: the process's arguments); returns the exit status."""
    a = _parser().parse_args(argv)
    if a.command == "export":  # no server involved
        try:
            return _export(a)
        except (errors.D3ILError, ValueError, OSError) as e:
            print(f"error: {e}", file=sys.stderr)
            return 1
    try:
        client = Client(a.server, a.token)
        return COMMANDS[a.command](client, a)
    except (errors.D3ILError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except OSError as e:  # connection refused, unreadable file
        print(f"error: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
