"""Exceptions of the D3IL leaderboard client.

Every error the server answers with (``{"error": {"code", "message", "field"}}``,
docs/api.md) becomes a :class:`ServerError` (or one of its subclasses) carrying the
server's code, message and field, so ``str(exc)`` says what the server said.
"""

from __future__ import annotations

from typing import Any, Optional


class D3ILError(Exception):
    """Base class of every error this package raises."""


class ManifestError(D3ILError, ValueError):
    """A policy manifest or a submission's arguments are wrong (found before sending)."""

    def __init__(self, message: str, field: Optional[str] = None) -> None:
        super().__init__(message)
        #: The manifest field or argument at fault, when there is one.
        self.field = field


class ConnectionFailed(D3ILError):
    """The server could not be reached (refused, reset, timed out)."""


class IncompatibleServer(D3ILError):
    """The server speaks another API version, or does not accept this client's version."""


class ServerError(D3ILError):
    """The server answered with an error status.

    Attributes carry the server's answer: ``status`` (HTTP status), ``code``
    (e.g. ``invalid``, ``not_found``, ``conflict``), ``message`` (what was
    wrong and what to do) and ``field`` (the request field at fault, or None).
    """

    def __init__(
        self,
        status: int,
        message: str,
        code: Optional[str] = None,
        field: Optional[str] = None,
        url: Optional[str] = None,
    ) -> None:
        self.status = status
        self.code = code
        self.message = message
        self.field = field
        self.url = url
        where = f" (field `{field}`)" if field else ""
        super().__init__(f"{status} {code or 'error'}: {message}{where}")


class BadRequest(ServerError):
    """400: a field is missing or invalid; ``field`` names it."""


class AuthenticationError(ServerError):
    """401: the token is missing, wrong or revoked."""


class Forbidden(ServerError):
    """403: the token may not do this."""


class NotFound(ServerError):
    """404: no such submission, task or endpoint (or no result yet)."""


class Conflict(ServerError):
    """409: e.g. this training seed was already submitted for the method and setting."""


class TooLarge(ServerError):
    """413: the upload is over the server's size or disk limit."""


class Unprocessable(ServerError):
    """422: e.g. a remote endpoint failed its conformance dry run."""


class RateLimited(ServerError):
    """429: too many requests; ``retry_after`` is the server's Retry-After in seconds."""

    def __init__(self, *args: Any, retry_after: Optional[float] = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.retry_after = retry_after


class QuotaExceeded(RateLimited):
    """429 ``quota_exceeded``: the submitter's submission quota allows none now.

    The message says when the next submission is possible; ``next_submission_at``
    is that time (unix seconds) when it is one (the daily quota), else None (the
    total quota, or evaluations still running: wait for one to finish).
    """

    def __init__(self, *args: Any, next_submission_at: Optional[int] = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.next_submission_at = next_submission_at


class EvaluationFailed(D3ILError):
    """The submission was accepted but its evaluation failed.

    ``kind`` is the server's error kind (``bad_model``, ``wall_clock``, ...) and
    ``submission`` the last :class:`~d3il_client.models.Submission` seen.
    """

    def __init__(self, submission: Any) -> None:
        self.submission = submission
        err = submission.error
        self.kind: Optional[str] = err.kind if err is not None else None
        message = err.message if err is not None and err.message else "no message"
        super().__init__(f"submission {submission.id} failed ({self.kind}): {message}")


class WaitTimeout(D3ILError, TimeoutError):
    """:meth:`Client.wait <d3il_client.Client.wait>` gave up before the evaluation finished."""


_BY_STATUS = {
    400: BadRequest,
    401: AuthenticationError,
    403: Forbidden,
    404: NotFound,
    409: Conflict,
    413: TooLarge,
    422: Unprocessable,
}


def error_for(status: int, body: Any, url: Optional[str], retry_after: Optional[float]) -> ServerError:
    """The exception for an error answer ``body`` (parsed JSON, or text) with ``status``."""
    code = field = None
    next_at: Optional[int] = None
    if isinstance(body, dict) and isinstance(body.get("error"), dict):
        detail = body["error"]
        if isinstance(detail.get("next_submission_at"), int):
            next_at = detail["next_submission_at"]
        message = str(detail.get("message") or "")
        code = detail.get("code")
        field = detail.get("field")
    else:
        text = body if isinstance(body, str) else ""
        message = text.strip()[:500] or "the server gave no message"
    if status == 429 and code == "quota_exceeded":
        return QuotaExceeded(status, message, code, field, url, retry_after=retry_after, next_submission_at=next_at)
    if status == 429:
        return RateLimited(status, message, code, field, url, retry_after=retry_after)
    cls = _BY_STATUS.get(status, ServerError)
    return cls(status, message, code, field, url)
