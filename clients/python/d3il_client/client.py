"""The API client: :class:`Client`."""

from __future__ import annotations

import os
import re
import secrets
import time
import warnings
from pathlib import Path
from typing import (
    TYPE_CHECKING,
    Any,
    Callable,
    Dict,
    Iterator,
    List,
    Mapping,
    Optional,
    Sequence,
    Tuple,
    Union,
    overload,
)

import requests

from . import errors
from ._version import API_VERSION, __version__
from .manifest import (
    OBS_TYPES,
    PROTOCOLS,
    SUITES,
    TASKS,
    ManifestArg,
    PathLike,
    check_choice,
    check_policy_file,
    load_manifest,
)
from .models import (
    Comparison,
    Leaderboard,
    LeaderboardLink,
    Method,
    Race,
    Results,
    RolloutItem,
    RolloutPage,
    Submission,
    SubmissionSummary,
    from_json,
    rollout_items_frame,
)

if TYPE_CHECKING:
    import pandas as pd

#: Where ``Client()`` connects without a ``server`` argument (or ``$D3IL_SERVER``).
DEFAULT_SERVER = "http://127.0.0.1:8080"

SubmissionRef = Union[int, Submission, SubmissionSummary]

#: The figures :meth:`Client.plot` saves: kind -> (what it needs, path under /plots).
PLOTS: Dict[str, Tuple[str, str]] = {
    "pareto": ("task", "/plots/tasks/{task}/pareto.svg"),
    "data-fraction": ("task", "/plots/tasks/{task}/data-fraction.svg"),
    "paths": ("submission", "/plots/submissions/{submission}/paths.svg"),
    "starts": ("submission", "/plots/submissions/{submission}/starts.svg"),
    "behaviours": ("submission", "/plots/submissions/{submission}/behaviours.svg"),
    "rollout-paths": ("rollout", "/plots/submissions/{submission}/rollouts/{rollout}/paths.svg"),
    "rollout-steps": ("rollout", "/plots/submissions/{submission}/rollouts/{rollout}/steps.svg"),
}


def _id(s: SubmissionRef) -> int:
    return s if isinstance(s, int) else s.id


def version_matches(version: str, spec: str) -> bool:
    """Whether ``version`` satisfies the PEP 440 specifier ``spec`` (e.g. ``>=1.0,<2``).

    Handles the operators ``==``, ``!=``, ``>=``, ``<=``, ``>``, ``<``, ``~=`` on
    release numbers (``1``, ``1.2``, ``1.2.3``; ``==1.*`` too), which is what the
    server publishes; pre-release and local parts of ``version`` are ignored.
    """

    def release(v: str) -> Tuple[int, ...]:
        m = re.match(r"\d+(\.\d+)*", v.strip())
        if not m:
            raise ValueError(f"not a version: {v!r}")
        return tuple(int(p) for p in m.group(0).split("."))

    def pad(a: Tuple[int, ...], n: int) -> Tuple[int, ...]:
        return a + (0,) * (n - len(a))

    mine = release(version)
    for clause in filter(None, (c.strip() for c in spec.split(","))):
        m = re.match(r"(~=|==|!=|>=|<=|>|<)\s*(.+)", clause)
        if not m:
            raise ValueError(f"not a version specifier: {clause!r}")
        op, v = m.groups()
        if v.endswith(".*") and op in ("==", "!="):
            prefix = release(v[:-2])
            same = mine[: len(prefix)] == prefix
            if same != (op == "=="):
                return False
            continue
        other = release(v)
        n = max(len(mine), len(other))
        a, b = pad(mine, n), pad(other, n)
        ok = {
            "==": a == b,
            "!=": a != b,
            ">=": a >= b,
            "<=": a <= b,
            ">": a > b,
            "<": a < b,
            "~=": a >= b and mine[: len(other) - 1] == other[:-1],
        }[op]
        if not ok:
            return False
    return True


class _MultipartUpload:
    """A multipart/form-data body that reads the file as it is sent (never whole in memory).

    ``requests`` streams a body that has ``read``/``__iter__``; ``__len__`` gives
    it the Content-Length, so the server can refuse an oversized upload at once.
    """

    CHUNK = 1 << 16

    def __init__(
        self,
        fields: Sequence[Tuple[str, str]],
        file_field: Optional[str],
        path: Optional[Path],
        on_bytes: Optional[Callable[[int], None]] = None,
    ) -> None:
        self.boundary = "d3il-client-" + secrets.token_hex(16)
        head = b"".join(
            f'--{self.boundary}\r\nContent-Disposition: form-data; name="{k}"\r\n\r\n'.encode() + v.encode() + b"\r\n"
            for k, v in fields
        )
        self._parts: List[Union[bytes, Path]] = [head]
        size = len(head)
        if file_field is not None and path is not None:
            name = path.name.replace('"', "%22").replace("\r", "").replace("\n", "")
            file_head = (
                f'--{self.boundary}\r\nContent-Disposition: form-data; name="{file_field}"; '
                f'filename="{name}"\r\nContent-Type: application/octet-stream\r\n\r\n'
            ).encode()
            self._parts += [file_head, path, b"\r\n"]
            size += len(file_head) + path.stat().st_size + 2
        tail = f"--{self.boundary}--\r\n".encode()
        self._parts.append(tail)
        self._len = size + len(tail)
        self._on_bytes = on_bytes
        self._chunks = self._generate()
        self._buffer = b""

    @property
    def content_type(self) -> str:
        return f"multipart/form-data; boundary={self.boundary}"

    def __len__(self) -> int:
        return self._len

    def _generate(self) -> Iterator[bytes]:
        for part in self._parts:
            if isinstance(part, bytes):
                yield part
                continue
            with open(part, "rb") as f:
                while True:
                    block = f.read(self.CHUNK)
                    if not block:
                        break
                    if self._on_bytes is not None:
                        self._on_bytes(len(block))
                    yield block

    def __iter__(self) -> Iterator[bytes]:
        if self._buffer:
            yield self._buffer
            self._buffer = b""
        yield from self._chunks

    def read(self, n: int = -1) -> bytes:
        """Up to ``n`` bytes of the body (all the rest with ``n < 0``)."""
        while n < 0 or len(self._buffer) < n:
            block = next(self._chunks, None)
            if block is None:
                break
            self._buffer += block
        if n < 0:
            out, self._buffer = self._buffer, b""
        else:
            out, self._buffer = self._buffer[:n], self._buffer[n:]
        return out


def _format_seconds(s: float) -> str:
    s = int(round(s))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{(s % 3600) // 60:02d}m"


def progress_line(sub: Submission) -> str:
    """One line of progress, as ``d3il submit --wait`` prints it.

    The status, then rollouts done of the total once the worker has said how
    many there are (until then the total is 0), or the queue position while
    queued; the server's ETA when it gives one.
    """
    p = sub.progress
    if p.rollouts_total > 0:
        line = f"{sub.status} {p.rollouts_done}/{p.rollouts_total}"
    elif sub.queue_position is not None:
        line = f"{sub.status}, {sub.queue_position} ahead in the queue"
    elif sub.status == "running":
        line = "running, starting"
    else:
        line = sub.status
    if sub.eta_seconds is not None and not sub.done:
        line += f", about {_format_seconds(sub.eta_seconds)} left"
    live = p.live
    if live is not None and live.success_rate is not None:
        line += (
            f", success so far {live.success_rate:.3f} [{live.cs_low:.3f}, {live.cs_high:.3f}] (valid at every look)"
        )
    return line


class Client:
    """A client of one D3IL leaderboard server's API (``/api/v1``, docs/api.md).

    ``server`` is the server's root URL (default ``$D3IL_SERVER``, else
    ``http://127.0.0.1:8080``); ``token`` an API token from ``d3il token create``
    (default ``$D3IL_TOKEN``), needed only to submit. Reading needs no token.

    Before its first request the client reads the server's OpenAPI document and
    raises :class:`~d3il_client.errors.IncompatibleServer` when the server
    speaks another API version or does not accept this client's version (it
    says which versions to install). Every error answer of the server raises a
    :class:`~d3il_client.errors.ServerError` carrying the server's message.
    """

    def __init__(
        self,
        server: Optional[str] = None,
        token: Optional[str] = None,
        *,
        timeout: float = 60.0,
        check_version: bool = True,
        session: Optional[requests.Session] = None,
    ) -> None:
        self.server = (server or os.environ.get("D3IL_SERVER") or DEFAULT_SERVER).rstrip("/")
        if not re.match(r"https?://", self.server):
            raise ValueError(f"server must be an http:// or https:// URL, got {self.server!r}")
        self.token = token if token is not None else os.environ.get("D3IL_TOKEN")
        self.timeout = timeout
        self._session = session or requests.Session()
        self._session.headers["User-Agent"] = f"d3il-client/{__version__}"
        self._check_version = check_version
        self._openapi: Optional[Dict[str, Any]] = None

    def __repr__(self) -> str:
        return f"Client({self.server!r})"

    # ---- plumbing -------------------------------------------------------------

    def _url(self, path: str) -> str:
        return self.server + (path if path.startswith("/") else "/" + path)

    def _send(self, method: str, path: str, *, auth: bool = False, retries: int = 5, **kw: Any) -> requests.Response:
        if self._check_version:
            self.check_server()
        headers = dict(kw.pop("headers", None) or {})
        if auth:
            if not self.token:
                raise errors.AuthenticationError(
                    401,
                    "no token: give Client(server, token) or set D3IL_TOKEN "
                    "(mint one with `d3il token create --name <you>` on the server)",
                )
            headers["Authorization"] = f"Bearer {self.token}"
        url = self._url(path)
        for attempt in range(retries + 1):
            try:
                resp = self._session.request(method, url, headers=headers, timeout=self.timeout, **kw)
            except (requests.ConnectionError, requests.Timeout) as e:
                raise errors.ConnectionFailed(f"{method} {url}: {e}") from e
            if resp.status_code < 400:
                return resp
            retry_after = _retry_after(resp)
            # Reads may wait out a rate limit; a submission is never sent twice.
            if resp.status_code == 429 and method == "GET" and attempt < retries:
                time.sleep(min(retry_after or 5.0, 60.0))
                continue
            raise _error(resp, retry_after)
        raise AssertionError("unreachable")

    def _get_json(self, path: str, params: Optional[Mapping[str, Any]] = None) -> Any:
        resp = self._send("GET", path, params=_clean(params))
        return _json(resp)

    def openapi(self) -> Dict[str, Any]:
        """The server's OpenAPI document (``/api/v1/openapi.json``), read once."""
        if self._openapi is None:
            url = self._url("/api/v1/openapi.json")
            try:
                resp = self._session.get(url, timeout=self.timeout)
            except (requests.ConnectionError, requests.Timeout) as e:
                raise errors.ConnectionFailed(f"cannot reach the D3IL leaderboard at {self.server}: {e}") from e
            if resp.status_code == 404:
                raise errors.IncompatibleServer(
                    f"{self.server} has no /api/v1/openapi.json: is it a D3IL leaderboard (d3il serve)?"
                )
            if resp.status_code >= 400:
                raise _error(resp, _retry_after(resp))
            doc = _json(resp)
            if not isinstance(doc, dict):
                raise errors.IncompatibleServer(f"{url} is not an OpenAPI document")
            self._openapi = doc
        return self._openapi

    def check_server(self) -> Tuple[str, Optional[str]]:
        """Check that the server accepts this client; return its API version and accepted client versions.

        Raises :class:`~d3il_client.errors.IncompatibleServer` with what to
        install when the server's ``info.version`` is not :data:`API_VERSION` or
        its ``info.x-d3il-client-versions`` excludes this client's version.
        """
        info = self.openapi().get("info") or {}
        api = str(info.get("version"))
        accepted = info.get("x-d3il-client-versions")
        ok = api == API_VERSION
        if ok and isinstance(accepted, str) and accepted.strip():
            ok = version_matches(__version__, accepted)
        if not ok:
            install = f"pip install 'd3il-client{accepted}'" if accepted else f"a d3il-client {api}.x"
            raise errors.IncompatibleServer(
                f"this d3il-client {__version__} speaks API version {API_VERSION}, but the server at "
                f"{self.server} speaks API version {api} and accepts d3il-client {accepted or 'of that version'}: "
                f"install {install}"
            )
        # Checked once: later requests skip it.
        self._check_version = False
        return api, accepted if isinstance(accepted, str) else None

    # ---- submitting -----------------------------------------------------------

    def whoami(self) -> str:
        """The submitter the token belongs to (checks the token)."""
        return str(_json(self._send("GET", "/api/v1/whoami", auth=True))["submitter"])

    def quota(self) -> Dict[str, Any]:
        """What is left of the token's submission quota (``GET /api/v1/whoami``'s ``quota``).

        ``exempt`` (admin tokens), ``per_day``, ``total`` and ``concurrent`` (each
        ``limit``, ``used``, ``remaining``; a None limit is none), ``remaining``
        (the least), ``next_submission_at`` (unix seconds, when the daily quota is
        spent) and ``summary`` (one sentence). Every :meth:`submit` answer carries
        it too, in the returned submission's ``raw["quota"]``; past it, submit
        raises :class:`~d3il_client.errors.QuotaExceeded`.
        """
        quota = _json(self._send("GET", "/api/v1/whoami", auth=True)).get("quota")
        if not isinstance(quota, dict):
            raise errors.IncompatibleServer("this server's /api/v1/whoami has no quota (an older server)")
        return quota

    def submit(
        self,
        *,
        method: str,
        task: str,
        training_seed: int,
        onnx: Optional[PathLike] = None,
        manifest: Optional[ManifestArg] = None,
        endpoint: Optional[str] = None,
        endpoint_secret: Optional[str] = None,
        obs_type: str = "state",
        data_fraction: float = 1.0,
        protocol: str = "paper",
        history: Optional[int] = None,
        backbone: Optional[str] = None,
        prediction: Optional[str] = None,
        diversity: Optional[str] = None,
        code_url: Optional[str] = None,
        paper_url: Optional[str] = None,
        description: Optional[str] = None,
        suite: Optional[str] = None,
        progress: bool = False,
    ) -> Submission:
        """Submit a policy: an ONNX file (``onnx=``) or a remote endpoint (``endpoint=``).

        The arguments are ``d3il submit``'s flags. An ONNX file's manifest is
        ``manifest`` (a path, or the manifest as a dict) or else the ``.json``
        next to the file. Before anything is sent, the manifest is checked as the
        server checks it, against ``task`` and ``obs_type`` too, and the file
        must exist and not be empty (:class:`~d3il_client.errors.ManifestError`).
        The file is streamed, never read whole into memory; ``progress=True``
        shows an upload bar.

        ``history``, ``backbone``, ``prediction``, ``diversity``, ``code_url``,
        ``paper_url`` and ``description`` describe the method (its page, its
        group in the paper's tables). ``suite="robustness"`` evaluates the
        task's perturbation suite too (every task for state policies, and the
        image variants of Aligning, Sorting-4/6 and Stacking; level 0 is the
        plain result, :meth:`robustness` has the rest). ``endpoint_secret``
        (with ``endpoint=``) is the shared secret the evaluator sends the
        endpoint (its server started with the same ``--secret``,
        docs/remote-protocol.md); the server stores it and never shows it again.
        Returns the queued
        :class:`~d3il_client.models.Submission`; follow it with :meth:`wait`.
        """
        if not method or len(method) > 64:
            raise errors.ManifestError("method must be 1-64 characters", "method")
        check_choice("task", task, TASKS)
        check_choice("obs_type", obs_type, OBS_TYPES)
        check_choice("protocol", protocol, PROTOCOLS)
        if suite is not None:
            check_choice("suite", suite, SUITES)
        if isinstance(training_seed, bool) or not isinstance(training_seed, int) or training_seed < 0:
            raise errors.ManifestError("training_seed must be a whole number >= 0", "training_seed")
        if not 0.0 < float(data_fraction) <= 1.0:
            raise errors.ManifestError(f"data_fraction {data_fraction} must be in (0, 1]", "data_fraction")
        if (onnx is None) == (endpoint is None):
            raise errors.ManifestError(
                "give onnx=FILE (its manifest next to it as FILE.json, or manifest=) or endpoint=URL, not both"
            )
        if endpoint_secret is not None and endpoint is None:
            raise errors.ManifestError("endpoint_secret goes with endpoint=URL", "endpoint_secret")
        fields: List[Tuple[str, str]] = [
            ("method", method),
            ("task", task),
            ("obs_type", obs_type),
            ("training_seed", str(training_seed)),
            ("data_fraction", repr(float(data_fraction))),
            ("protocol", protocol),
        ]
        for key, value in (
            ("history", None if history is None else str(history)),
            ("backbone", backbone),
            ("prediction", prediction),
            ("diversity", diversity),
            ("code_url", code_url),
            ("paper_url", paper_url),
            ("description", description),
            ("suite", suite),
        ):
            if value is not None:
                fields.append((key, value))
        path: Optional[Path] = None
        if onnx is not None:
            size = check_policy_file(onnx)
            parsed, text = load_manifest(onnx, manifest)
            if parsed["task"] != task:
                raise errors.ManifestError(
                    f"the manifest is for task {parsed['task']} but the submission is for {task}", "task"
                )
            if parsed.get("obs_type", "state") != obs_type:
                raise errors.ManifestError(
                    f"the manifest's obs_type is {parsed.get('obs_type', 'state')} but the submission's is {obs_type}",
                    "obs_type",
                )
            fields.append(("manifest", text))
            path = Path(onnx)
        else:
            assert endpoint is not None
            if not re.match(r"(wss?|https?)://", endpoint):
                raise errors.ManifestError(
                    f"endpoint must be a ws://, wss://, http:// or https:// URL, got {endpoint!r}", "endpoint_url"
                )
            fields.append(("endpoint_url", endpoint))
            if endpoint_secret is not None:
                fields.append(("endpoint_secret", endpoint_secret))
            if manifest is not None:
                fields.append(("manifest", load_manifest(None, manifest)[1]))
        bar: Any = None
        if progress and path is not None:
            from tqdm.auto import tqdm

            bar = tqdm(total=size, unit="B", unit_scale=True, desc=f"uploading {path.name}", leave=False)
        body = _MultipartUpload(fields, "onnx" if path else None, path, bar.update if bar else None)
        try:
            resp = self._send(
                "POST",
                "/api/v1/submissions",
                auth=True,
                data=body,
                headers={"Content-Type": body.content_type},
                retries=0,
            )
        finally:
            if bar is not None:
                bar.close()
        return from_json(Submission, _json(resp))

    # ---- following ------------------------------------------------------------

    def submission(self, submission: SubmissionRef) -> Submission:
        """A submission and how its evaluation stands.

        With a token, a remote endpoint's URL is there for its submitter (and
        admins); the server shows it to nobody else.
        """
        resp = self._send("GET", f"/api/v1/submissions/{_id(submission)}", auth=self.token is not None)
        return from_json(Submission, _json(resp))

    @overload
    def cancel(self, work: Race) -> Race: ...

    @overload
    def cancel(self, work: SubmissionRef) -> Submission: ...

    def cancel(self, work: Union[SubmissionRef, Race]) -> Union[Submission, Race]:
        """Cancel a queued or running evaluation or race (its submitter or an admin may).

        An evaluation: what ran is kept as a partial result (``progress.live``,
        ``partial`` true), never ranked; the submission is then ``failed``
        with error kind ``cancelled``. A race (a :class:`Race`, as
        :meth:`race` returns it): ``cancelled``, its worker stopped
        (:meth:`cancel_race` takes its id).
        """
        if isinstance(work, Race):
            return self.cancel_race(work.id)
        resp = self._send("POST", f"/api/v1/submissions/{_id(work)}/cancel", auth=True)
        return from_json(Submission, _json(resp))

    def cancel_race(self, race: int) -> Race:
        """Cancel a queued or running race (``POST /api/v1/races/{id}/cancel``; its starter or an admin).

        The race ends ``cancelled`` (``cancelled_by`` says who) and its
        worker is stopped; a race that has ended is a 409 ``ServerError``.
        """
        resp = self._send("POST", f"/api/v1/races/{int(race)}/cancel", auth=True)
        return from_json(Race, _json(resp))

    def submissions(
        self,
        *,
        task: Optional[str] = None,
        method: Optional[str] = None,
        status: Optional[str] = None,
        submitter: Optional[str] = None,
    ) -> List[SubmissionSummary]:
        """Submissions, newest first (at most 500), filtered by exact task, method, status, submitter.

        Withdrawn submissions are left out (as of the boards); ``submission(id)`` still finds one.
        """
        doc = self._get_json(
            "/api/v1/submissions", {"task": task, "method": method, "status": status, "submitter": submitter}
        )
        return [from_json(SubmissionSummary, s) for s in doc["submissions"]]

    def wait(
        self,
        submission: SubmissionRef,
        *,
        timeout: float = 7200.0,
        poll: float = 2.0,
        progress: bool = True,
        on_update: Optional[Callable[[Submission], None]] = None,
    ) -> Submission:
        """Wait until the evaluation finished and return the completed submission.

        Shows a tqdm progress bar of rollouts done (``progress=False``: none)
        with the queue position or the server's estimate of the time left;
        ``on_update`` is called with every new state seen. The server being
        unreachable for a while (a restart: accepted jobs survive it) is waited
        out until ``timeout``. Raises
        :class:`~d3il_client.errors.EvaluationFailed` (with the server's error
        kind and message) when the evaluation failed, and
        :class:`~d3il_client.errors.WaitTimeout` after ``timeout`` seconds.
        """
        sid = _id(submission)
        deadline = time.monotonic() + timeout
        bar: Any = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=0, unit="rollout", desc=f"submission {sid}", leave=True)
        try:
            while True:
                try:
                    sub = self.submission(sid)
                except errors.ConnectionFailed:
                    if time.monotonic() >= deadline:
                        raise
                    time.sleep(max(0.05, min(poll, deadline - time.monotonic())))
                    continue
                if on_update is not None:
                    on_update(sub)
                if bar is not None:
                    _update_bar(bar, sub)
                if sub.status == "failed":
                    raise errors.EvaluationFailed(sub)
                if sub.status == "completed":
                    return sub
                if time.monotonic() >= deadline:
                    raise errors.WaitTimeout(
                        f"submission {sid} is still {progress_line(sub)} after {timeout:.0f} s; "
                        f"wait again or see {self.server}{sub.url}"
                    )
                time.sleep(max(0.05, min(poll, deadline - time.monotonic())))
        finally:
            if bar is not None:
                bar.close()

    # ---- results --------------------------------------------------------------

    def results(self, submission: SubmissionRef) -> Results:
        """The results of a completed evaluation (metrics, per initial state, per rollout).

        Raises :class:`~d3il_client.errors.NotFound` until the evaluation completed.
        """
        return from_json(Results, self._get_json(f"/api/v1/submissions/{_id(submission)}/results"))

    def robustness(self, submission: SubmissionRef, *, rollouts: bool = False) -> Dict[str, Any]:
        """The robustness document of a submission made with ``suite="robustness"``.

        Level 0 (``control``), every perturbed level with its paired drop, the
        axes' scores and the overall score (docs/robustness.md). Without
        ``rollouts=True`` the rollout records are left out (much smaller).
        Raises :class:`~d3il_client.errors.NotFound` until the evaluation completed.
        """
        doc: Dict[str, Any] = self._get_json(
            f"/api/v1/submissions/{_id(submission)}/robustness", {"rollouts": "true" if rollouts else "false"}
        )
        return doc

    def robustness_frame(self, submission: SubmissionRef) -> pd.DataFrame:
        """The robustness document as a DataFrame, one row per level (level 0 first, axis ``control``).

        Columns: ``axis``, ``level``, ``setting``, ``success_rate``, ``ci_low``,
        ``ci_high``, ``drop``, ``drop_ci_low``, ``drop_ci_high``, ``p_value``,
        ``retained``, ``conditional_entropy``.
        """
        import pandas as pd

        doc = self.robustness(submission)
        m0 = doc["control"]["metrics"]
        rows: List[Dict[str, Any]] = [
            {
                "axis": "control",
                "level": 0,
                "setting": "standard protocol",
                "success_rate": m0["success_rate"]["value"],
                "ci_low": m0["success_rate"]["ci_low"],
                "ci_high": m0["success_rate"]["ci_high"],
                "drop": None,
                "drop_ci_low": None,
                "drop_ci_high": None,
                "p_value": None,
                "retained": 1.0,
                "conditional_entropy": m0["conditional_entropy"]["value"],
            }
        ]
        for lv in doc["levels"]:
            m = lv["result"]["metrics"]
            d = lv["paired"]["success_rate"]
            rows.append(
                {
                    "axis": lv["axis"],
                    "level": lv["level"],
                    "setting": lv["setting"]["label"],
                    "success_rate": m["success_rate"]["value"],
                    "ci_low": m["success_rate"]["ci_low"],
                    "ci_high": m["success_rate"]["ci_high"],
                    "drop": d["difference"]["value"],
                    "drop_ci_low": d["difference"]["ci_low"],
                    "drop_ci_high": d["difference"]["ci_high"],
                    "p_value": d["p_value"],
                    "retained": lv["retained"],
                    "conditional_entropy": m["conditional_entropy"]["value"],
                }
            )
        frame: pd.DataFrame = pd.DataFrame(rows)
        return frame

    def rollouts_page(
        self,
        submission: SubmissionRef,
        *,
        outcome: Optional[str] = None,
        behaviour: Optional[str] = None,
        context: Optional[int] = None,
        page: int = 1,
        per_page: int = 500,
    ) -> RolloutPage:
        """One page of a submission's rollouts, filtered (docs/api.md, ``/rollouts``).

        ``outcome`` is ``success``, ``failure``, ``unstable`` or ``time_limit``;
        ``behaviour`` a behaviour name (``1-2-3``, ``RB``); ``context`` an
        initial state's index.
        """
        doc = self._get_json(
            f"/api/v1/submissions/{_id(submission)}/rollouts",
            {"outcome": outcome, "behaviour": behaviour, "context": context, "page": page, "per_page": per_page},
        )
        return from_json(RolloutPage, doc)

    def rollouts(
        self,
        submission: SubmissionRef,
        *,
        outcome: Optional[str] = None,
        behaviour: Optional[str] = None,
        context: Optional[int] = None,
    ) -> List[RolloutItem]:
        """Every rollout matching the filters (all pages of :meth:`rollouts_page`)."""
        items: List[RolloutItem] = []
        page = 1
        while True:
            p = self.rollouts_page(submission, outcome=outcome, behaviour=behaviour, context=context, page=page)
            items.extend(p.items)
            if page >= p.pages:
                return items
            page += 1

    def rollouts_frame(
        self,
        submission: SubmissionRef,
        *,
        outcome: Optional[str] = None,
        behaviour: Optional[str] = None,
        context: Optional[int] = None,
    ) -> pd.DataFrame:
        """The rollouts as a DataFrame, one row per rollout.

        Columns: ``number``, ``context``, ``rollout``, ``success``,
        ``behaviour``, ``behaviour_label``, ``steps``, ``ending``,
        ``ending_text``, ``failure_reason``, ``failure_message``,
        ``failure_step``, ``has_trace``, ``record`` and ``video`` (links).
        """
        try:
            items = self.rollouts(submission, outcome=outcome, behaviour=behaviour, context=context)
        except errors.NotFound as e:
            # A server from before the rollouts endpoint: the results document's
            # rollouts (without names or links), unfiltered.
            if "no such API endpoint" not in e.message or any(v is not None for v in (outcome, behaviour, context)):
                raise
            return self.results(submission).rollouts_frame()
        return rollout_items_frame(items)

    def rollout_record(self, submission: SubmissionRef, number: int, path: Optional[PathLike] = None) -> Any:
        """One rollout's record with its trace; saved to ``path`` it replays with ``d3il replay --result``."""
        resp = self._send("GET", f"/api/v1/submissions/{_id(submission)}/rollouts/{number}")
        if path is not None:
            Path(path).write_bytes(resp.content)
        return _json(resp)

    def download_video(self, submission: SubmissionRef, number: int, path: PathLike) -> Path:
        """Save rollout ``number``'s video (MP4, both cameras) to ``path``; the server renders it on demand."""
        return self._download(f"/api/v1/submissions/{_id(submission)}/rollouts/{number}/video", path)

    # ---- comparing and leaderboards -------------------------------------------

    def compare(self, a: SubmissionRef, b: SubmissionRef) -> Comparison:
        """The paired comparison A − B of two completed submissions on the same task, protocol and initial states."""
        return from_json(Comparison, self._get_json("/api/v1/compare", {"a": _id(a), "b": _id(b)}))

    def race(
        self,
        a: SubmissionRef,
        b: SubmissionRef,
        alpha: float = 0.05,
        delta: Optional[float] = None,
        wait: bool = True,
        *,
        protocol: Optional[str] = None,
        seed: Optional[int] = None,
        timeout: float = 7200.0,
        poll: float = 1.0,
        on_update: Optional[Callable[[Race], None]] = None,
    ) -> Race:
        """Race submissions ``a`` and ``b`` on the server (``POST /api/v1/races``, issue 41).

        Both policies run interleaved on the same initial states in the same
        random order; the race stops as soon as the anytime-valid paired test
        decides at ``alpha`` ("A better", "B better", or with ``delta`` "no
        difference larger than δ"), or at the protocol's full size
        (``protocol``: ``paper``, the default, or ``quick``). With ``wait``
        (default) returns the finished race (``decision``,
        ``report``), else the queued one, whose ``raw["quota"]`` is what is
        left of the quota after it (as :meth:`quota` shows it; a race counts
        as two evaluations); ``on_update`` sees every state
        polled (``live``: pairs so far, paired counts, e-value, anytime
        p-value). Raises :class:`~d3il_client.errors.ServerError` (with the
        field) for a wrong request, ``RuntimeError`` (with the server's
        reason) when the race failed, and
        :class:`~d3il_client.errors.WaitTimeout` after ``timeout`` seconds.
        """
        body: Dict[str, Any] = {"a": _id(a), "b": _id(b), "alpha": alpha}
        for k, v in (("delta", delta), ("protocol", protocol), ("seed", seed)):
            if v is not None:
                body[k] = v
        resp = self._send("POST", "/api/v1/races", auth=True, json=body)
        race = from_json(Race, _json(resp))
        if not wait:
            return race
        deadline = time.monotonic() + timeout
        while True:
            if on_update is not None:
                on_update(race)
            if race.status == "completed":
                return race
            if race.status in ("failed", "cancelled"):
                raise RuntimeError(f"race {race.id} {race.status}: {race.error}")
            if time.monotonic() >= deadline:
                raise errors.WaitTimeout(
                    f"race {race.id} is still {race.status} after {timeout:.0f} s; "
                    f"wait again with client.get_race({race.id})"
                )
            time.sleep(max(0.05, min(poll, deadline - time.monotonic())))
            race = self.get_race(race.id)

    def get_race(self, race: int) -> Race:
        """A race (``GET /api/v1/races/{id}``): status, live state, report."""
        return from_json(Race, self._get_json(f"/api/v1/races/{int(race)}"))

    def comparison(self, comparison: int) -> Race:
        """Deprecated: :meth:`get_race` (a race was called a comparison before it had its own name)."""
        warnings.warn(
            "Client.comparison(id) is deprecated; use Client.get_race(id) (the paired comparison "
            "of two finished results is Client.compare(a, b))",
            DeprecationWarning,
            stacklevel=2,
        )
        return self.get_race(comparison)

    def leaderboards(self) -> List[LeaderboardLink]:
        """Every leaderboard (task × observation type)."""
        return [from_json(LeaderboardLink, x) for x in self._get_json("/api/v1/leaderboards")["leaderboards"]]

    def leaderboard(self, task: str, obs: str = "state", *, view: str = "main") -> Leaderboard:
        """A task's leaderboard: reported and evaluated rows (``view="data-fraction"``: every data fraction).

        ``.frame()`` gives it as a DataFrame.
        """
        check_choice("obs", obs, OBS_TYPES)
        return from_json(Leaderboard, self._get_json(f"/api/v1/leaderboards/{task}", {"obs": obs, "view": view}))

    def methods(self) -> List[Method]:
        """Every method with its properties."""
        return [from_json(Method, m) for m in self._get_json("/api/v1/methods")["methods"]]

    def download_csv(self, task: str, path: PathLike, obs: str = "state", *, view: str = "main") -> Path:
        """Save a task's leaderboard as CSV (the server's columns) to ``path``; returns the path."""
        check_choice("obs", obs, OBS_TYPES)
        return self._download(f"/api/v1/leaderboards/{task}/csv", path, {"obs": obs, "view": view})

    def plot(
        self,
        kind: str,
        path: PathLike,
        *,
        task: Optional[str] = None,
        submission: Optional[SubmissionRef] = None,
        rollout: Optional[int] = None,
        obs: str = "state",
    ) -> Path:
        """Save one of the server's figures (SVG) to ``path``; returns the path.

        ``kind`` is ``pareto`` or ``data-fraction`` (give ``task`` and
        ``obs``), ``paths``, ``starts`` or ``behaviours`` (give
        ``submission``), ``rollout-paths`` or ``rollout-steps`` (give
        ``submission`` and ``rollout``).
        """
        if kind not in PLOTS:
            raise ValueError(f"plot kind {kind!r} is not one of {', '.join(PLOTS)}")
        needs, template = PLOTS[kind]
        params: Optional[Dict[str, Any]] = None
        if needs == "task":
            if task is None:
                raise ValueError(f"the {kind} plot needs task=")
            check_choice("obs", obs, OBS_TYPES)
            url = template.format(task=task)
            params = {"obs": obs}
        else:
            if submission is None or (needs == "rollout" and rollout is None):
                raise ValueError(f"the {kind} plot needs submission=" + (" and rollout=" if needs == "rollout" else ""))
            url = template.format(submission=_id(submission), rollout=rollout)
        return self._download(url, path, params)

    def _download(self, url: str, path: PathLike, params: Optional[Mapping[str, Any]] = None) -> Path:
        resp = self._send("GET", url, params=_clean(params), stream=True)
        out = Path(path)
        with open(out, "wb") as f:
            for block in resp.iter_content(1 << 16):
                f.write(block)
        return out


def _clean(params: Optional[Mapping[str, Any]]) -> Optional[Dict[str, Any]]:
    return None if params is None else {k: v for k, v in params.items() if v is not None}


def _retry_after(resp: requests.Response) -> Optional[float]:
    try:
        return float(resp.headers["Retry-After"])
    except (KeyError, ValueError):
        return None


def _json(resp: requests.Response) -> Any:
    try:
        return resp.json()
    except ValueError as e:
        raise errors.ServerError(
            resp.status_code, f"the server's answer is not JSON: {resp.text[:200]!r}", url=resp.url
        ) from e


def _error(resp: requests.Response, retry_after: Optional[float]) -> errors.ServerError:
    try:
        body: Any = resp.json()
    except ValueError:
        body = resp.text
    return errors.error_for(resp.status_code, body, resp.url, retry_after)


def _update_bar(bar: Any, sub: Submission) -> None:
    p = sub.progress
    if p.rollouts_total > 0 and bar.total != p.rollouts_total:
        bar.total = p.rollouts_total
    if p.rollouts_done != bar.n:
        bar.n = p.rollouts_done
    status = sub.status
    if sub.queue_position is not None and p.rollouts_total == 0:
        status += f", {sub.queue_position} ahead"
    bar.set_description(f"submission {sub.id} {status}", refresh=False)
    eta = f"server ETA {_format_seconds(sub.eta_seconds)}" if sub.eta_seconds is not None else ""
    bar.set_postfix_str(eta, refresh=False)
    bar.refresh()
