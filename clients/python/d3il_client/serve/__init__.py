"""Serve a policy or a D3IL reference agent to the leaderboard's evaluator.

The remote protocol (docs/remote-protocol.md): a WebSocket with msgpack frames,
which the evaluator connects to when a submission names an endpoint.
:func:`serve` serves a batched callable ``policy(obs, request)``,
:func:`serve_agent` an object with the reference agents' ``reset()`` /
``predict(obs)`` (one agent state per rollout). From the shell::

    python -m d3il_client.serve --agent my_module:make_agent --checkpoint ckpt.pth --port 8765
    python -m d3il_client.serve --demo avoiding --port 8765

Needs the ``serve`` extra: ``pip install 'd3il-client[serve]'``.
"""

from .agent import AgentAdapter, agent_server, serve_agent
from .policy import (
    DEMOS,
    PROTOCOL_VERSION,
    PolicyServer,
    Request,
    avoiding_policy,
    pack_array,
    packb,
    serve,
    tls_context,
    unpack_array,
    unpackb,
    zeros_policy,
)

__all__ = [
    "DEMOS",
    "PROTOCOL_VERSION",
    "AgentAdapter",
    "PolicyServer",
    "Request",
    "agent_server",
    "avoiding_policy",
    "pack_array",
    "packb",
    "serve",
    "serve_agent",
    "tls_context",
    "unpack_array",
    "unpackb",
    "zeros_policy",
]
