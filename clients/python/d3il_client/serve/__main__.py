"""``python -m d3il_client.serve``: serve an agent, a policy callable or a demo policy.

    python -m d3il_client.serve --agent my_module:make_agent --checkpoint ckpt.pth --task aligning --port 8765
    python -m d3il_client.serve --policy my_module:policy --history 5 --port 8765
    python -m d3il_client.serve --demo avoiding --port 0

``--agent MODULE:NAME`` names a class or function (MODULE importable from the
current directory or ``sys.path``); it is called once, with the checkpoint path
when ``--checkpoint`` is given, and must return an object with the reference
agents' ``reset()`` and ``predict(obs)``: it is deep-copied for every rollout
(``d3il_client.serve.serve_agent``). An agent of a D3IL family that
``d3il_client.agents`` recognises is served batched (one model call per request
group, torch needed); any other per rollout (one ``predict`` per rollout and step).
Before serving, an agent's cost is measured on a dummy request of ``--max-live``
rollouts (the evaluator's 96 by default) and the projected inference time of the
``--task``'s paper protocol (every task's without ``--task``) is printed against
the default wall limit of an evaluation, with a loud warning when it will not fit
(``--no-measure`` skips this). ``--policy MODULE:NAME`` names a batched
callable ``policy(obs, request)`` served with ``--history/--horizon/--execute``.
Prints ``listening on HOST:PORT`` once it accepts connections; submit it as
``ws://HOST:PORT/`` (``wss://`` with ``--certfile``). ``--secret`` (or
``$D3IL_ENDPOINT_SECRET``) serves only a client that sends the same secret: submit
the endpoint with it (docs/remote-protocol.md, "Shared secret").
"""

from __future__ import annotations

import argparse
import os
from typing import List, Optional

from .. import tasks
from ..objects import load_object, make_agent
from .agent import make_adapter, startup_projection
from .policy import DEMOS, SECRET_ENV, check_secret, serve


def main(argv: Optional[List[str]] = None) -> None:
    """Parse ``argv`` and serve until interrupted."""
    ap = argparse.ArgumentParser(
        prog="python -m d3il_client.serve", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    what = ap.add_mutually_exclusive_group()
    what.add_argument("--agent", metavar="MODULE:NAME", help="class or factory of a reference-style agent")
    what.add_argument("--policy", metavar="MODULE:NAME", help="batched callable policy(obs, request)")
    what.add_argument("--demo", choices=sorted(DEMOS), help="built-in policy to serve (default zeros)")
    ap.add_argument("--checkpoint", help="with --agent: passed to MODULE:NAME as its one argument")
    ap.add_argument(
        "--task",
        choices=sorted(tasks.PAPER_PROTOCOL),
        help="with --agent: the task whose paper protocol the startup projection is for",
    )
    ap.add_argument(
        "--max-live",
        type=int,
        default=tasks.MAX_LIVE,
        help="with --agent: rollouts per request to measure at (the evaluator's --max-live)",
    )
    ap.add_argument("--no-measure", action="store_true", help="with --agent: skip the startup measurement")
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=8765, help="0 picks a free port (printed)")
    ap.add_argument("--history", type=int, default=1, help="observations per query (not with --agent)")
    ap.add_argument("--horizon", type=int, default=1, help="actions returned per query (not with --agent)")
    ap.add_argument("--execute", type=int, default=1, help="actions executed per query (not with --agent)")
    ap.add_argument("--certfile", help="PEM certificate chain (leaf first): serve TLS (wss://)")
    ap.add_argument("--keyfile", help="PEM private key of --certfile (if not in the same file)")
    ap.add_argument(
        "--secret",
        default=os.environ.get(SECRET_ENV) or None,
        help=f"serve only a client that sends this shared secret (the evaluator, when the endpoint is "
        f"submitted with it); default ${SECRET_ENV}, which, unlike this option, other users cannot see in ps",
    )
    a = ap.parse_args(argv)
    if a.secret is not None:
        try:
            check_secret(a.secret)
        except ValueError as e:
            ap.error(str(e))
    if a.keyfile and not a.certfile:
        ap.error("--keyfile needs --certfile")
    if a.checkpoint and not a.agent:
        ap.error("--checkpoint goes with --agent")
    if a.task and not a.agent:
        ap.error("--task goes with --agent")
    if a.agent:
        if (a.history, a.horizon, a.execute) != (1, 1, 1):
            ap.error("an agent is served with history = horizon = execute = 1 (it keeps its own window)")
        agent = make_agent(a.agent, a.checkpoint)
        adapter = make_adapter(agent)
        if not a.no_measure:
            startup_projection(adapter, a.task, max_live=a.max_live)
        serve(
            adapter,
            host=a.host,
            port=a.port,
            certfile=a.certfile,
            keyfile=a.keyfile,
            history=1,
            horizon=1,
            execute=1,
            reset=adapter.reset,
            forget=adapter.forget,
            secret=a.secret,
        )
        return
    policy = load_object(a.policy) if a.policy else DEMOS[a.demo or "zeros"]
    serve(
        policy,
        host=a.host,
        port=a.port,
        certfile=a.certfile,
        keyfile=a.keyfile,
        history=a.history,
        horizon=a.horizon,
        execute=a.execute,
        secret=a.secret,
    )


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:
        pass
