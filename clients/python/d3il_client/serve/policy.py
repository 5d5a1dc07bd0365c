"""Reference server for D3IL leaderboard remote policies (docs/remote-protocol.md).

Serve any Python callable to the evaluator over a WebSocket with msgpack frames:

    import numpy as np
    from d3il_client.serve import serve

    def policy(obs, request):
        # obs: float32 [B, k, obs_dim] (oldest first); request.rollout_ids, .steps,
        # .images (image policies), .spec (the task spec the evaluator sent)
        return np.zeros((obs.shape[0], 1, request.spec["act_dim"]), np.float32)

    serve(policy, host="127.0.0.1", port=8765, history=1, horizon=1, execute=1)

The callable returns float32 actions [B, H, act_dim] (or [B, act_dim] when H = 1).
An optional `reset(rollout_ids)` callable is told when episodes start.

Command line: `python -m d3il_client.serve --demo zeros --port 8765` serves a
built-in demo policy (see --help); add `--certfile cert.pem --keyfile key.pem`
to serve TLS (wss://). Requirements: the `serve` extra (numpy, websockets, msgpack).
"""

from __future__ import annotations

import asyncio
import dataclasses
import hmac
import ssl as ssl_module
import sys
import traceback
from http import HTTPStatus
from typing import IO, Any, Callable, Dict, Optional, Set

import msgpack
import numpy as np
from websockets.asyncio.server import serve as ws_serve
from websockets.exceptions import ConnectionClosed

#: The remote protocol's version this server speaks (docs/remote-protocol.md).
PROTOCOL_VERSION = 1

#: A policy: float32 observations [B, k, obs_dim] and the request -> actions [B, H, act_dim].
Policy = Callable[[np.ndarray, "Request"], Any]


def pack_array(a: np.ndarray) -> Dict[str, Any]:
    """openpi-style array: {"__ndarray__": True, "data", "dtype", "shape"}."""
    a = np.ascontiguousarray(a)
    return {"__ndarray__": True, "data": a.tobytes(), "dtype": a.dtype.str, "shape": list(a.shape)}


def _key(d: Dict[Any, Any], k: str) -> Any:
    # Accept str and bytes keys (openpi's packer writes bytes keys).
    if k in d:
        return d[k]
    return d.get(k.encode())


def unpack_array(d: Dict[Any, Any]) -> np.ndarray:
    """The numpy array of an openpi-style packed array (str or bytes keys)."""
    if not isinstance(d, dict) or not _key(d, "__ndarray__"):
        raise ValueError("expected an {__ndarray__, data, dtype, shape} array")
    dtype = _key(d, "dtype")
    if isinstance(dtype, bytes):
        dtype = dtype.decode()
    shape = tuple(int(n) for n in _key(d, "shape"))
    return np.frombuffer(_key(d, "data"), dtype=np.dtype(dtype)).reshape(shape)


def packb(msg: Dict[str, Any]) -> bytes:
    """A message as one msgpack frame."""
    out: bytes = msgpack.packb(msg, use_bin_type=True)
    return out


def unpackb(data: bytes) -> Dict[Any, Any]:
    """One msgpack frame as a message."""
    out: Dict[Any, Any] = msgpack.unpackb(data, raw=False, strict_map_key=False)
    return out


@dataclasses.dataclass
class Request:
    """What the evaluator asks for in one `infer`, next to the observations."""

    rollout_ids: np.ndarray  # uint64 [B]
    steps: np.ndarray  # uint64 [B]
    spec: Dict[str, Any]  # the task spec the evaluator sent (task, obs_dim, act_dim, seed, ...)
    images: Optional[np.ndarray] = None  # float32 [B, k, 2, 3, 96, 96] for image policies


class PolicyServer:
    """Serves one callable; one evaluator connection at a time is typical, but
    each connection gets its own spec.
    """

    def __init__(
        self,
        policy: Policy,
        *,
        history: int = 1,
        horizon: int = 1,
        execute: int = 1,
        reset: Optional[Callable[[np.ndarray], None]] = None,
        forget: Optional[Callable[[np.ndarray], None]] = None,
        max_live_rollouts: int = 4096,
        max_frame_bytes: int = 64 << 20,
        secret: Optional[str] = None,
        log: IO[str] = sys.stderr,
    ) -> None:
        if not (1 <= execute <= horizon) or history < 1:
            raise ValueError("need history >= 1 and 1 <= execute <= horizon")
        if max_live_rollouts < 1:
            raise ValueError("need max_live_rollouts >= 1")
        if secret is not None:
            check_secret(secret)
        # With a secret, only a handshake that carries it (`Authorization:
        # Bearer SECRET`, what the evaluator sends) gets a connection.
        self.secret = secret
        self.policy = policy
        self.history, self.horizon, self.execute = history, horizon, execute
        self.reset_fn = reset
        # What a policy keeps per rollout is freed when the rollout's episode
        # ends: at the connection's next `reset` (a new episode batch) for the
        # rollouts it no longer names, and when the connection closes.
        self.forget_fn = forget
        # A connection may keep at most this many rollouts live at once (a
        # client naming ever new rollout ids cannot grow the server's memory).
        self.max_live_rollouts = max_live_rollouts
        self.max_frame_bytes = max_frame_bytes
        self.log = log

    def _live(self, state: Dict[str, Any], ids: np.ndarray, new_episode: bool) -> None:
        """Track the connection's live rollouts; refuse past the cap, free ended ones."""
        names = {int(i) for i in ids}
        live: Set[int] = state.setdefault("live", set())
        if new_episode:
            ended = live - names
            if ended and self.forget_fn is not None:
                self.forget_fn(np.array(sorted(ended), dtype=np.uint64))
            live = names
        else:
            live = live | names
        if len(live) > self.max_live_rollouts:
            raise ValueError(
                f"{len(live)} live rollouts on this connection; this endpoint keeps at most "
                f"{self.max_live_rollouts} (max_live_rollouts)"
            )
        state["live"] = live

    def authorize(self, connection: Any, request: Any) -> Any:
        """The handshake check (websockets' `process_request`): None lets a
        request that carries the secret through; any other gets 401 and says why.
        """
        if self.secret is None:
            return None
        sent = request.headers.get("Authorization")
        peer = getattr(connection, "remote_address", None)
        if sent is None:
            why = (
                "this endpoint needs its shared secret: the handshake has no `Authorization: Bearer` header "
                "(submit the endpoint with its secret, docs/remote-protocol.md)"
            )
        elif not (sent.startswith("Bearer ") and hmac.compare_digest(sent[7:].encode(), self.secret.encode())):
            # compare_digest: the time taken does not tell how much of the secret matched.
            why = "the shared secret sent does not match this endpoint's"
        else:
            return None
        print(f"refused a connection from {peer}: {why}", file=self.log, flush=True)
        return connection.respond(HTTPStatus.UNAUTHORIZED, why + "\n")

    def hello(self) -> Dict[str, Any]:
        """The first message of a connection: protocol version and k/H/E."""
        return {
            "type": "hello",
            "protocol": PROTOCOL_VERSION,
            "history": self.history,
            "horizon": self.horizon,
            "execute": self.execute,
        }

    async def handle(self, msg: Dict[Any, Any], state: Dict[str, Any]) -> Dict[str, Any]:
        """Answer one decoded request; raising turns into an `error` message."""
        kind = _key(msg, "type")
        if kind == "spec":
            state["spec"] = {k if isinstance(k, str) else k.decode(): v for k, v in msg.items()}
            return {"type": "ready"}
        if "spec" not in state:
            raise ValueError("the first message must be `spec`")
        if kind == "reset":
            ids = np.asarray(_key(msg, "rollout_ids"), dtype=np.uint64)
            self._live(state, ids, new_episode=True)
            if self.reset_fn is not None:
                await asyncio.to_thread(self.reset_fn, ids)
            return {"type": "ok"}
        if kind == "infer":
            spec = state["spec"]
            obs = unpack_array(_key(msg, "obs")).astype(np.float32, copy=False)
            images = _key(msg, "images")
            ids = np.asarray(_key(msg, "rollout_ids"), dtype=np.uint64)
            self._live(state, ids, new_episode=False)
            req = Request(
                rollout_ids=ids,
                steps=np.asarray(_key(msg, "steps"), dtype=np.uint64),
                spec=spec,
                images=unpack_array(images) if images is not None else None,
            )
            # Run the model off the event loop so pings keep being answered.
            actions = await asyncio.to_thread(self.policy, obs, req)
            actions = np.asarray(actions, dtype=np.float32)
            if actions.ndim == 2:
                actions = actions[:, None, :]
            return {"type": "actions", "id": _key(msg, "id"), "actions": pack_array(actions)}
        raise ValueError(f"unknown message type {kind!r}")

    async def reply(self, ws: Any, request_type: Any, reply: Dict[str, Any]) -> None:
        """Send one reply (a hook so test servers can misbehave)."""
        await ws.send(packb(reply))

    async def connection(self, ws: Any) -> None:
        """Serve one evaluator connection until it closes."""
        state: Dict[str, Any] = {}
        try:
            await self.reply(ws, "hello", self.hello())
            async for frame in ws:
                if isinstance(frame, str):
                    await ws.send(packb({"type": "error", "message": "send binary msgpack frames"}))
                    continue
                try:
                    msg = unpackb(frame)
                    kind = _key(msg, "type")
                    reply = await self.handle(msg, state)
                except Exception as e:  # report to the evaluator, keep serving
                    traceback.print_exc(file=self.log)
                    kind = "error"
                    reply = {"type": "error", "message": f"{type(e).__name__}: {e}"}
                await self.reply(ws, kind, reply)
        except ConnectionClosed:
            pass
        finally:
            live = state.get("live")
            if live and self.forget_fn is not None:
                self.forget_fn(np.array(sorted(live), dtype=np.uint64))

    async def run(
        self,
        host: str,
        port: int,
        ready: Optional[Callable[[int], None]] = None,
        ssl: Optional[ssl_module.SSLContext] = None,
    ) -> None:
        """Serve until cancelled; with `ssl` (a server-side SSLContext) the
        endpoint is wss:// instead of ws://.
        """
        async with ws_serve(
            self.connection,
            host,
            port,
            max_size=self.max_frame_bytes,
            ssl=ssl,
            process_request=self.authorize if self.secret is not None else None,
        ) as server:
            bound = server.sockets[0].getsockname()[1]
            if ready is not None:
                ready(bound)
            await server.serve_forever()


#: Environment variable holding an endpoint's shared secret: read by
#: ``python -m d3il_client.serve`` (when --secret is not given), by
#: ``d3il-client submit --endpoint`` and by ``d3il submit`` / ``d3il eval``.
SECRET_ENV = "D3IL_ENDPOINT_SECRET"

#: Shortest and longest secret accepted (the server's `endpoint_secret` rule).
SECRET_MIN_LEN, SECRET_MAX_LEN = 16, 256


def check_secret(secret: str) -> None:
    """Refuse a secret the leaderboard would refuse: 16-256 visible ASCII characters."""
    if not (SECRET_MIN_LEN <= len(secret) <= SECRET_MAX_LEN):
        raise ValueError(
            f"the endpoint secret has {len(secret)} characters; give {SECRET_MIN_LEN} to {SECRET_MAX_LEN} "
            "(e.g. python3 -c 'import secrets; print(secrets.token_urlsafe(32))')"
        )
    if not all("!" <= c <= "~" for c in secret):
        raise ValueError("the endpoint secret must be visible ASCII characters only (no spaces)")


def tls_context(certfile: str, keyfile: Optional[str] = None) -> ssl_module.SSLContext:
    """A server-side TLS context from a PEM certificate chain (leaf first) and its key."""
    ctx = ssl_module.SSLContext(ssl_module.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl_module.TLSVersion.TLSv1_2
    ctx.load_cert_chain(certfile, keyfile)
    return ctx


def serve(
    policy: Policy,
    host: str = "127.0.0.1",
    port: int = 8765,
    certfile: Optional[str] = None,
    keyfile: Optional[str] = None,
    **kwargs: Any,
) -> None:
    """Blocking: serve `policy` until interrupted. Prints the bound port.

    Binds 127.0.0.1 unless `host` says otherwise (``host="0.0.0.0"`` publishes
    it on every interface). With `certfile` (PEM chain, leaf first) and
    `keyfile` the server speaks TLS, i.e. submit it as wss://host:port/. With
    ``secret="..."`` it serves only a client that sends it (the evaluator, when
    the endpoint was submitted with the same ``endpoint_secret``).
    """
    server = PolicyServer(policy, **kwargs)
    ctx = tls_context(certfile, keyfile) if certfile else None

    def ready(p: int) -> None:
        print(f"listening on {host}:{p}", flush=True)

    asyncio.run(server.run(host, port, ready, ssl=ctx))


# ---- demo policies -------------------------------------------------------------


def zeros_policy(obs: np.ndarray, req: Request) -> np.ndarray:
    """Zero actions, whatever the observation."""
    return np.zeros((obs.shape[0], 1, req.spec["act_dim"]), np.float32)


def avoiding_policy(obs: np.ndarray, req: Request) -> np.ndarray:
    """Avoiding steering of assets/fixtures/avoiding_path.onnx in numpy: desired x
    towards 0.57 / 0.50 / 0.575 by desired y, |dx| <= 0.008, dy = 0.008.
    """
    x, y = obs[:, -1, 0], obs[:, -1, 1]
    tx = np.where(y < -0.04, 0.57, np.where(y < 0.16, 0.50, 0.575))
    dx = np.clip(tx - x, -0.008, 0.008)
    return np.stack([dx, np.full_like(dx, 0.008)], axis=1).astype(np.float32)


#: The built-in demo policies of `python -m d3il_client.serve --demo NAME`.
DEMOS: Dict[str, Policy] = {"zeros": zeros_policy, "avoiding": avoiding_policy}
