"""Serve a policy or a D3IL reference agent to the leaderboard's evaluator.

The remote protocol (docs/remote-protocol.md): a WebSocket with msgpack frames,
which the evaluator connects to when a submission names an endpoint.
:func:`serve` serves a batched callable ``policy(obs, request)``,
:func:`serve_agent` an object with the reference agents' ``reset()`` /
``predict(obs)``: batched (one model call per request group) when
``d3il_client.agents`` knows its family, else one agent state per rollout. From the shell::

    python -m d3il_client.serve --agent my_module:make_agent --checkpoint ckpt.pth --task aligning
    python -m d3il_client.serve --demo avoiding --port 8765

Needs the ``serve`` extra: ``pip install 'd3il-client[serve]'``.
"""

from .agent import AgentAdapter, BatchedAgentAdapter, agent_server, make_adapter, serve_agent, startup_projection
from .policy import (
    DEMOS,
    PROTOCOL_VERSION,
    SECRET_ENV,
    PolicyServer,
    Request,
    avoiding_policy,
    check_secret,
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
    "SECRET_ENV",
    "AgentAdapter",
    "BatchedAgentAdapter",
    "PolicyServer",
    "Request",
    "agent_server",
    "make_adapter",
    "avoiding_policy",
    "check_secret",
    "pack_array",
    "packb",
    "serve",
    "serve_agent",
    "startup_projection",
    "tls_context",
    "unpack_array",
    "unpackb",
    "zeros_policy",
]
