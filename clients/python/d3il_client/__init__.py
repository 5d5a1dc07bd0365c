"""d3il-client: submit policies to a D3IL leaderboard and read what it found.

    from d3il_client import Client

    client = Client("http://127.0.0.1:8080", token="d3il_...")
    sub = client.submit(onnx="policy.onnx", method="my-bc", task="aligning", training_seed=0)
    client.wait(sub)
    print(client.results(sub).metrics_frame())

Submodules: :mod:`d3il_client.export` (export recipes for D3IL agents, needs the
``export`` extra), :mod:`d3il_client.serve` (serve a policy or a reference agent
over the remote protocol, needs the ``serve`` extra; ``python -m
d3il_client.serve``). The command line is ``d3il-client``.
"""

from ._version import API_VERSION, __version__
from .client import Client, version_matches
from .errors import (
    AuthenticationError,
    BadRequest,
    Conflict,
    ConnectionFailed,
    D3ILError,
    EvaluationFailed,
    Forbidden,
    IncompatibleServer,
    ManifestError,
    NotFound,
    QuotaExceeded,
    RateLimited,
    ServerError,
    TooLarge,
    Unprocessable,
    WaitTimeout,
)
from .manifest import validate_manifest
from .models import (
    Comparison,
    ContextResult,
    Estimate,
    Leaderboard,
    LeaderboardLink,
    LeaderboardRow,
    LiveEstimate,
    Method,
    Metrics,
    PairedDifference,
    Race,
    Results,
    Rollout,
    RolloutItem,
    RolloutPage,
    Submission,
    SubmissionSummary,
)

__all__ = [
    "API_VERSION",
    "AuthenticationError",
    "BadRequest",
    "Client",
    "Comparison",
    "Conflict",
    "ConnectionFailed",
    "ContextResult",
    "D3ILError",
    "Estimate",
    "EvaluationFailed",
    "Forbidden",
    "IncompatibleServer",
    "Leaderboard",
    "LeaderboardLink",
    "LeaderboardRow",
    "LiveEstimate",
    "ManifestError",
    "Method",
    "Metrics",
    "NotFound",
    "PairedDifference",
    "Race",
    "QuotaExceeded",
    "RateLimited",
    "Results",
    "Rollout",
    "RolloutItem",
    "RolloutPage",
    "ServerError",
    "Submission",
    "SubmissionSummary",
    "TooLarge",
    "Unprocessable",
    "WaitTimeout",
    "__version__",
    "validate_manifest",
    "version_matches",
]
