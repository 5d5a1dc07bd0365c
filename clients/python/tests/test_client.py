"""The API client against a real server: submitting, following, results, errors."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import tqdm.auto
from conftest import FIXTURES, Pair, Server, d3il_bin, run_server

import d3il_client
from d3il_client import Client, errors
from d3il_client.client import _MultipartUpload, _update_bar, progress_line, version_matches
from d3il_client.models import Submission, from_json
from d3il_client.text import comparison_table, metrics_table


def submission_count(client: Client) -> int:
    return len(client.submissions())


def test_results_come_as_typed_objects_and_frames(client: Client, evaluated: Pair) -> None:
    sub = client.submission(evaluated.path)
    assert sub.status == "completed" and sub.done
    assert sub.policy.kind == "onnx" and sub.policy.sha256 and sub.policy.bytes
    assert sub.progress.rollouts_done == sub.progress.rollouts_total == 8
    res = client.results(evaluated.path)
    assert res == sub.result, "the status document embeds the results document"
    assert res.metrics.success_rate.value == 1.0
    assert res.protocol_manifest["policy_sha256"] == sub.policy.sha256
    assert res.initial_states == "avoiding-v1.json"
    assert len(res.rollouts) == 8 and all(r.ending == "task_success" for r in res.rollouts)
    metrics = res.metrics_frame().set_index("metric")
    assert metrics.loc["success_rate", "value"] == 1.0
    assert list(res.contexts_frame().context) == [0]
    from_results = res.rollouts_frame()
    from_list = client.rollouts_frame(evaluated.path)
    assert list(from_results.number) == list(from_list.number) == list(range(8))
    assert list(from_results.success) == list(from_list.success)
    assert from_list.record[0] == f"/api/v1/submissions/{sub.id}/rollouts/0"
    assert set(from_list.ending_text) == {"the task succeeded"} or len(set(from_list.ending_text)) == 1


def test_rollout_filters_and_pages(client: Client, evaluated: Pair) -> None:
    everything = client.rollouts_page(evaluated.noise)
    assert everything.all == everything.total == 8
    failures = client.rollouts(evaluated.noise, outcome="failure")
    successes = client.rollouts(evaluated.noise, outcome="success")
    assert len(failures) + len(successes) == 8
    assert all(not r.success for r in failures) and all(r.success for r in successes)
    page = client.rollouts_page(evaluated.noise, per_page=3, page=2)
    assert (page.page, page.pages, [r.number for r in page.items]) == (2, 3, [3, 4, 5])
    with pytest.raises(errors.BadRequest) as e:
        client.rollouts(evaluated.noise, outcome="sideways")
    assert e.value.field == "outcome" and "success" in e.value.message


def test_compare_is_paired_and_refuses_what_cannot_be_paired(client: Client, evaluated: Pair) -> None:
    c = client.compare(evaluated.path, evaluated.noise)
    assert (c.task, c.protocol, c.n_contexts, c.rollouts_per_context) == ("avoiding", "quick", 1, 8)
    assert c.success_rate.a == 1.0
    assert c.success_rate.difference.value == pytest.approx(c.success_rate.a - c.success_rate.b)
    same = client.compare(evaluated.path, evaluated.path)
    assert same.success_rate.p_value == 1.0 and same.success_rate.difference.value == 0.0
    table = comparison_table(c)
    assert table.startswith("paired comparison A − B: task avoiding, quick protocol, 1 initial states × 8 rollouts")
    with pytest.raises(errors.NotFound) as e:
        client.compare(evaluated.path, 999999)
    assert "999999" in e.value.message and e.value.status == 404


def test_server_errors_carry_the_servers_message(server: Server, evaluated: Pair) -> None:
    client = Client(server.base, server.token)
    with pytest.raises(errors.Conflict) as e:
        client.submit(
            onnx=FIXTURES / "avoiding_path.onnx",
            method="pytest-path",
            task="avoiding",
            training_seed=0,
            protocol="quick",
        )
    assert e.value.field == "training_seed"
    assert "already submitted" in str(e.value) and f"submission {evaluated.path.id}" in e.value.message
    with pytest.raises(errors.AuthenticationError) as auth:
        Client(server.base, "d3il_not-a-token").whoami()
    assert auth.value.status == 401 and auth.value.message
    with pytest.raises(errors.AuthenticationError, match="D3IL_TOKEN"):
        Client(server.base, "").submit(
            onnx=FIXTURES / "avoiding_path.onnx", method="x", task="avoiding", training_seed=9
        )
    with pytest.raises(errors.NotFound, match="not found"):
        client.results(999999)
    with pytest.raises(errors.BadRequest) as bad:
        client.leaderboard("avoiding", view="sideways")
    assert bad.value.field == "view"


def test_submit_checks_before_sending(client: Client, tmp_path: Path) -> None:
    before = submission_count(client)
    onnx = FIXTURES / "avoiding_path.onnx"
    cases: list[tuple[dict[str, object], str]] = [
        (dict(onnx=tmp_path / "missing.onnx"), "does not exist"),
        (dict(onnx=onnx, manifest={"task": "avoiding", "history": 0}), "history k = 0"),
        (dict(onnx=onnx, manifest={"task": "avoiding", "horizon": 2, "execute": 3}), "execute E = 3"),
        (dict(onnx=onnx, manifest={"task": "aligning"}), "for task aligning"),
        (dict(onnx=onnx, manifest={"task": "avoiding", "obs_type": "image"}), "obs_type is image"),
        (
            dict(onnx=onnx, manifest={"task": "avoiding", "normalisation": {"obs_std": [1, 0, 1, 1]}}),
            "positive everywhere",
        ),
        (dict(onnx=onnx, manifest=tmp_path / "none.json"), "reading the policy manifest"),
        (dict(onnx=onnx, protocol="slow"), "protocol `slow`"),
        (dict(onnx=onnx, data_fraction=1.5), "data_fraction"),
        (dict(onnx=onnx, endpoint="ws://127.0.0.1:1/"), "not both"),
        (dict(endpoint="ftp://example/"), "ws://"),
        (dict(), "give onnx=FILE"),
    ]
    empty = tmp_path / "empty.onnx"
    empty.write_bytes(b"")
    cases.append((dict(onnx=empty, manifest=FIXTURES / "avoiding_path.json"), "is empty"))
    for kwargs, words in cases:
        with pytest.raises(errors.ManifestError, match=words.replace("(", r"\(")):
            client.submit(method="pytest-checks", task="avoiding", training_seed=0, **kwargs)  # type: ignore[arg-type]
    assert submission_count(client) == before, "nothing was sent"


def test_the_upload_is_streamed_with_its_length(tmp_path: Path) -> None:
    big = tmp_path / "big.onnx"
    big.write_bytes(bytes(range(256)) * 4096)  # 1 MiB
    seen: list[int] = []
    body = _MultipartUpload([("method", "m"), ("manifest", '{"task": "avoiding"}')], "onnx", big, seen.append)
    chunks = list(iter(body))
    assert max(len(c) for c in chunks) <= _MultipartUpload.CHUNK
    data = b"".join(chunks)
    assert len(data) == len(body)
    assert sum(seen) == big.stat().st_size
    assert bytes(range(256)) * 4096 in data and data.endswith(f"--{body.boundary}--\r\n".encode())
    again = _MultipartUpload([("a", "b")], "onnx", big)
    assert len(again.read(10)) == 10 and len(again.read()) == len(again) - 10


def test_wait_shows_progress_and_the_servers_eta(
    server: Server, evaluated: Pair, monkeypatch: pytest.MonkeyPatch
) -> None:
    client = Client(server.base, server.token)
    sub = client.submit(
        onnx=FIXTURES / "avoiding_path.onnx", method="pytest-wait", task="avoiding", training_seed=1, protocol="quick"
    )
    seen: list[Submission] = []
    out = io.StringIO()
    real = tqdm.auto.tqdm

    def to_out(*args: Any, **kwargs: Any) -> Any:
        return real(*args, **{**kwargs, "file": out})

    monkeypatch.setattr(tqdm.auto, "tqdm", to_out)
    done = client.wait(sub, poll=0.1, on_update=seen.append)
    assert done.status == "completed" and seen[-1].status == "completed"
    assert f"submission {sub.id} completed" in out.getvalue() and "8/8" in out.getvalue()
    # Quick runs take under a second, so the server gives them no estimate (it
    # gives one of a second or more); a longer run's bar and line show it.
    doc = dict(done.raw, status="running", progress={"rollouts_done": 2, "rollouts_total": 8}, eta_seconds=75)
    running = from_json(Submission, doc)
    bar = to_out(total=0)
    _update_bar(bar, running)
    bar.close()
    assert "2/8" in out.getvalue() and "server ETA 1m15s" in out.getvalue()
    # The line `d3il submit --wait` prints, with and without an estimate.
    assert progress_line(running) == "running 2/8, about 1m15s left"
    doc.update(status="queued", progress={"rollouts_done": 0, "rollouts_total": 0}, queue_position=2, eta_seconds=None)
    assert progress_line(from_json(Submission, doc)) == "queued, 2 ahead in the queue"


def test_a_model_refused_at_submission_says_why(server: Server) -> None:
    client = Client(server.base, server.token)
    with pytest.raises(errors.BadRequest) as e:
        client.submit(
            onnx=FIXTURES / "hostile_nan.onnx", method="pytest-nan", task="avoiding", training_seed=0, protocol="quick"
        )
    assert e.value.field == "onnx" and "non-finite action (NaN)" in e.value.message


def test_a_failed_evaluation_raises_with_the_servers_error(tmp_path: Path) -> None:
    # Without the upload's dry run the NaN policy is queued and fails at its evaluation.
    with run_server(tmp_path, "--no-upload-dry-run") as server:
        client = Client(server.base, server.token)
        sub = client.submit(
            onnx=FIXTURES / "hostile_nan.onnx", method="pytest-nan", task="avoiding", training_seed=0, protocol="quick"
        )
        with pytest.raises(errors.EvaluationFailed) as e:
            client.wait(sub, progress=False, timeout=900)
    assert e.value.kind == "bad_action", e.value
    assert e.value.submission.error is not None and e.value.submission.status == "failed"
    assert str(e.value).startswith(f"submission {sub.id} failed (bad_action): ")
    assert "NaN" in str(e.value)


def test_leaderboards_and_files(client: Client, evaluated: Pair, tmp_path: Path) -> None:
    board = client.leaderboard("avoiding")
    frame = board.frame()
    assert "pytest-path" in set(frame.method)
    row = next(r for r in board.rows if r.method == "pytest-path")
    assert row.source == "evaluated" and evaluated.path.id in row.submission_ids
    assert row.success.mean == 1.0
    assert {"BC-MLP", "BESO"} <= set(frame[frame.source == "reported"].method)
    assert any(link.task == "avoiding" for link in client.leaderboards())
    assert any(m.name == "pytest-path" and m.backbone == "MLP" for m in client.methods())
    csv = client.download_csv("avoiding", tmp_path / "a.csv")
    assert "pytest-path" in csv.read_text()
    svg = client.plot("pareto", tmp_path / "pareto.svg", task="avoiding")
    assert "<svg" in svg.read_text()
    with pytest.raises(ValueError, match="needs submission"):
        client.plot("paths", tmp_path / "x.svg")
    record = client.rollout_record(evaluated.path, 3, tmp_path / "r3.json")
    assert json.loads((tmp_path / "r3.json").read_text()) == record
    assert record["summary"]["number"] == 3
    table = metrics_table(client.results(evaluated.path), client.rollouts(evaluated.path))
    assert table.splitlines()[0] == "task avoiding, state observations (1 x 8 rollouts, quick protocol, seed 0)"
    assert "behaviours of the 8 successful rollouts:" in table


def test_a_server_that_does_not_accept_this_client_says_what_to_install(
    server: Server, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(d3il_client.client, "__version__", "2.0.0")
    with pytest.raises(errors.IncompatibleServer) as e:
        Client(server.base).leaderboards()
    assert "d3il-client 2.0.0" in str(e.value) and "pip install 'd3il-client>=1.0,<2'" in str(e.value)
    monkeypatch.setattr(d3il_client.client, "__version__", "1.0.0")
    monkeypatch.setattr(d3il_client.client, "API_VERSION", "2")
    with pytest.raises(errors.IncompatibleServer, match="speaks API version 1"):
        Client(server.base).leaderboards()
    # Without the check the request goes through.
    assert Client(server.base, check_version=False).leaderboards()


def test_an_unreachable_server_is_a_clear_error() -> None:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(errors.ConnectionFailed, match=f"cannot reach the D3IL leaderboard at http://127.0.0.1:{port}"):
        Client(f"http://127.0.0.1:{port}").leaderboards()


def test_version_specifiers() -> None:
    assert version_matches("1.0.0", ">=1.0,<2")
    assert version_matches("1.4.2", ">=1.0,<2")
    assert not version_matches("2.0.0", ">=1.0,<2")
    assert not version_matches("0.9", ">=1.0,<2")
    assert version_matches("1.2.3", "==1.*") and not version_matches("2.0", "==1.*")
    assert version_matches("1.4", "~=1.2") and not version_matches("2.0", "~=1.2")
    assert version_matches("1.0.0rc1", ">=1.0")
    with pytest.raises(ValueError):
        version_matches("1.0", "=>1")


def test_quota_left_and_a_refusal_that_says_when(tmp_path: Path) -> None:
    """Issue 42: the quota left is in whoami and in every submit answer (and
    the CLI prints it as `d3il submit` does); past it, QuotaExceeded carries
    the time of the next possible submission."""
    with run_server(tmp_path, "--quota-per-day", "1", "--quota-total", "0", "--quota-concurrent", "0") as server:
        c = Client(server.base, server.token)
        before = c.quota()
        assert before["per_day"]["limit"] == 1 and before["per_day"]["remaining"] == 1, before
        first = c.submit(
            onnx=FIXTURES / "avoiding_path.onnx", method="q", task="avoiding", training_seed=0, protocol="quick"
        )
        assert first.raw["quota"]["remaining"] == 0, first.raw
        assert c.quota()["per_day"]["used"] == 1
        with pytest.raises(errors.QuotaExceeded) as refused:
            c.submit(
                onnx=FIXTURES / "avoiding_path.onnx", method="q", task="avoiding", training_seed=1, protocol="quick"
            )
        e = refused.value
        assert e.status == 429 and e.code == "quota_exceeded", e
        assert e.next_submission_at is not None and e.next_submission_at > first.created_at, e
        assert isinstance(e, errors.RateLimited)
        # A large file: the server refuses before reading it and reads on while
        # the client sends it, so the refusal arrives rather than a reset.
        big = tmp_path / "big.onnx"
        big.write_bytes(bytes(range(256)) * (32 << 12))
        shutil.copy(FIXTURES / "avoiding_path.json", tmp_path / "big.json")
        with pytest.raises(errors.QuotaExceeded) as refused:
            c.submit(onnx=big, method="q", task="avoiding", training_seed=2, protocol="quick")
        assert refused.value.next_submission_at == e.next_submission_at, refused.value
        assert "daily evaluation quota reached" in str(refused.value), refused.value


def test_race_returns_a_typed_race_and_refuses_a_submission_against_itself(
    client: Client, evaluated: Pair, monkeypatch: pytest.MonkeyPatch
) -> None:
    paths: list[str] = []
    send = client._send

    def recording(method: str, path: str, **kw: Any) -> Any:
        paths.append(path)
        return send(method, path, **kw)

    monkeypatch.setattr(client, "_send", recording)
    seen: list[d3il_client.Race] = []
    race = client.race(evaluated.path, evaluated.noise, protocol="quick", poll=0.2, on_update=seen.append)
    assert isinstance(race, d3il_client.Race), race
    assert race.status == "completed" and race.report is not None, race
    assert (race.a, race.b, race.alpha, race.protocol) == (evaluated.path.id, evaluated.noise.id, 0.05, "quick")
    # Avoiding has one initial state: one pair, too few to decide at 5 %.
    assert race.report["pairs_used"] == race.report["states_full"] == 1
    assert race.decision is None
    assert race.rollouts_used == race.report["rollouts_full"]
    assert race.live is not None and race.live.pairs == 1
    assert race.live.both + race.live.only_a + race.live.only_b + race.live.neither == 1
    assert (race.live.only_a, race.live.only_b) == tuple(race.report["discordant"])
    assert seen and seen[-1] == race
    assert client.get_race(race.id) == race
    # The client speaks the races' own routes, not their deprecated aliases.
    assert paths and all(p.startswith("/api/v1/races") for p in paths), paths
    assert "/api/v1/races" in paths, paths
    # The old names still work, with a DeprecationWarning.
    with pytest.warns(DeprecationWarning, match="get_race"):
        assert client.comparison(race.id) == race
    with pytest.warns(DeprecationWarning, match="d3il_client.Race"):
        assert d3il_client.models.RaceComparison is d3il_client.Race
    with pytest.raises(errors.ServerError) as e:
        client.race(evaluated.path, evaluated.path)
    assert e.value.field == "b" and "different submissions" in e.value.message


def test_a_race_is_cancelled_by_its_starter_only_once_and_its_answer_carries_the_quota(tmp_path: Path) -> None:
    """cancel_race (and cancel given the race) against a real server: the
    race ends `cancelled`, by whom, its worker stopped; another submitter may
    not cancel it, and a race that has ended cannot be cancelled again. The
    race's answer carries the quota after it, as a submission's does (a
    server with a daily quota, so that usage is counted)."""
    with run_server(tmp_path, "--quota-per-day", "100", "--quota-total", "0", "--quota-concurrent", "0") as server:
        client = Client(server.base, server.token)
        a, b = (
            client.wait(
                client.submit(
                    onnx=FIXTURES / f"avoiding_{name}.onnx",
                    method=f"race-{name}",
                    task="avoiding",
                    training_seed=0,
                    protocol="quick",
                ),
                timeout=900,
                progress=False,
            )
            for name in ("path", "noise")
        )
        before = client.quota()
        # The paper protocol's rollouts on both sides: still queued or running when cancelled.
        race = client.race(a, b, protocol="paper", wait=False)
        assert race.status in ("queued", "running"), race
        quota = race.raw["quota"]
        assert quota["per_day"]["used"] == before["per_day"]["used"] + 2, (before, quota)
        assert quota["races"]["used"] == before["races"]["used"] + 1 == 1, (before, quota)
        assert quota["exempt"] is False and set(quota) == set(before), quota

        stranger = subprocess.run(
            [d3il_bin(), "token", "create", "--name", "pytest-stranger", "--db", server.db],
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()
        with pytest.raises(errors.Forbidden) as refused:
            Client(server.base, stranger).cancel_race(race.id)
        assert refused.value.status == 403, refused.value

        cancelled = client.cancel(race)  # a Race goes to cancel_race
        assert cancelled.id == race.id and cancelled.status == "cancelled", cancelled
        assert cancelled.cancelled_by == "pytest", cancelled
        assert client.get_race(race.id).status == "cancelled"
        with pytest.raises(errors.Conflict) as again:
            client.cancel_race(race.id)
        assert again.value.status == 409, again.value
        # Cancelled, it no longer holds a race slot.
        assert client.quota()["races"]["used"] == 0
