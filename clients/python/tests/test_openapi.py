"""Every answer the client reads is checked against the server's own OpenAPI document
(/api/v1/openapi.json), and every field the client's models read is one the document
publishes, so the client cannot drift from the server unnoticed."""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Any

import jsonschema
import pytest
import referencing
import referencing.jsonschema
import requests
from conftest import Pair, Server

import d3il_client
from d3il_client import Client, models
from d3il_client.client import PLOTS

ROOT = "urn:d3il:openapi"


@pytest.fixture(scope="module")
def document(server: Server) -> dict[str, Any]:
    doc: dict[str, Any] = requests.get(server.base + "/api/v1/openapi.json", timeout=30).json()
    return doc


def validator(document: dict[str, Any], schema: dict[str, Any]) -> jsonschema.Draft202012Validator:
    resource = referencing.Resource.from_contents(document, default_specification=referencing.jsonschema.DRAFT202012)
    registry: referencing.Registry[Any] = referencing.Registry().with_resource(ROOT, resource)
    return jsonschema.Draft202012Validator(
        {"$ref": f"{ROOT}#{pointer(schema)}"} if "$ref" in schema else schema, registry=registry
    )


def pointer(schema: dict[str, Any]) -> str:
    ref = str(schema["$ref"])
    assert ref.startswith("#/"), ref
    return ref[1:]


def response_schema(document: dict[str, Any], method: str, path: str, status: str = "200") -> dict[str, Any]:
    op = document["paths"][path][method]
    schema: dict[str, Any] = op["responses"][status]["content"]["application/json"]["schema"]
    return schema


def check(document: dict[str, Any], method: str, path: str, body: Any, status: str = "200") -> None:
    schema = response_schema(document, method, path, status)
    assert schema != {"type": "object"}, f"{method.upper()} {path} has no schema of its own in the document"
    errors = sorted(validator(document, schema).iter_errors(body), key=lambda e: list(e.path))
    assert not errors, f"{method.upper()} {path}: " + "; ".join(
        f"{'/'.join(map(str, e.path))}: {e.message}" for e in errors[:5]
    )


def test_the_document_names_the_api_version_and_the_accepted_client_versions(document: dict[str, Any]) -> None:
    info = document["info"]
    assert info["version"] == d3il_client.API_VERSION
    accepted = info["x-d3il-client-versions"]
    assert d3il_client.version_matches(d3il_client.__version__, accepted), accepted
    assert d3il_client.__version__.split(".")[0] == d3il_client.API_VERSION


def test_every_answer_the_client_reads_is_what_the_document_describes(
    server: Server, evaluated: Pair, document: dict[str, Any], tmp_path: Path
) -> None:
    c = Client(server.base, server.token)
    a, b = evaluated.path.id, evaluated.noise.id
    check(
        document,
        "get",
        "/whoami",
        requests.get(
            server.base + "/api/v1/whoami", headers={"Authorization": f"Bearer {server.token}"}, timeout=30
        ).json(),
    )
    assert c.whoami() == "pytest"
    created = c.submit(
        onnx=Path(__file__).resolve().parents[3] / "assets/fixtures/avoiding_path.onnx",
        method="pytest-openapi",
        task="avoiding",
        training_seed=3,
        protocol="quick",
    )
    check(document, "post", "/submissions", created.raw, status="201")
    c.wait(created, progress=False, timeout=900)
    checked = {
        "/submissions/{id}": [c.submission(a).raw, c.submission(created).raw],
        "/submissions": [requests.get(server.base + "/api/v1/submissions", timeout=30).json()],
        "/submissions/{id}/results": [c.results(a).raw, c.results(b).raw],
        "/submissions/{id}/rollouts": [
            c.rollouts_page(a).raw,
            c.rollouts_page(b, outcome="failure", per_page=2).raw,
        ],
        "/compare": [c.compare(a, b).raw, c.compare(b, a).raw],
        "/leaderboards": [requests.get(server.base + "/api/v1/leaderboards", timeout=30).json()],
        "/leaderboards/{task}": [
            c.leaderboard("avoiding").raw,
            c.leaderboard("aligning", "image").raw,
            c.leaderboard("avoiding", view="data-fraction").raw,
        ],
        "/methods": [requests.get(server.base + "/api/v1/methods", timeout=30).json()],
        "/submissions/{id}/rollouts/{n}": [c.rollout_record(a, 0)],
    }
    # The typed lists came from the same documents.
    assert c.submissions(task="avoiding") and c.leaderboards() and c.methods()
    for path, bodies in checked.items():
        for body in bodies:
            check(document, "get", path, body)
    # Error answers have the documented shape too.
    for bad in ("/api/v1/submissions/999999", "/api/v1/compare?a=1"):
        resp = requests.get(server.base + bad, timeout=30)
        assert resp.status_code in (400, 404)
        errors = list(validator(document, {"$ref": "#/components/schemas/Error"}).iter_errors(resp.json()))
        assert not errors, errors
    # The CSV and the figures are what the document says they are.
    csv = c.download_csv("avoiding", tmp_path / "board.csv").read_text()
    assert csv.startswith("task,obs_type,method,source,protocol,")
    assert "text/csv" in document["paths"]["/leaderboards/{task}/csv"]["get"]["responses"]["200"]["content"]
    for kind in PLOTS:
        out = c.plot(kind, tmp_path / f"{kind}.svg", task="avoiding", submission=a, rollout=0)
        assert out.read_text().lstrip().startswith("<svg"), kind


def hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls, vars(models))


def test_every_field_the_models_read_is_published(document: dict[str, Any]) -> None:
    schemas = document["components"]["schemas"]
    for model in models.MODELS:
        name = str(model.SCHEMA)
        assert name in schemas, f"{model.__name__} mirrors {name}, which the document does not publish"
        schema = schemas[name]
        props = schema.get("properties", {})
        required = set(schema.get("required", []))
        for f in dataclasses.fields(model):
            if f.name == "raw":
                continue
            assert f.name in props, f"{model.__name__}.{f.name} is not a property of {name}"
            optional_here = f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
            assert optional_here or f.name in required, (
                f"{model.__name__}.{f.name} is required by the client but optional in {name}"
            )
        # Every property the server always sends is read.
        names = {f.name for f in dataclasses.fields(model)}
        assert required <= names, f"{model.__name__} lacks {sorted(required - names)} of {name}"


def test_the_models_are_the_documents_of_their_paths(document: dict[str, Any]) -> None:
    paths: dict[str, Any] = {
        "/submissions/{id}": models.Submission,
        "/submissions/{id}/results": models.Results,
        "/submissions/{id}/rollouts": models.RolloutPage,
        "/compare": models.Comparison,
        "/leaderboards/{task}": models.Leaderboard,
    }
    for path, model in paths.items():
        assert response_schema(document, "get", path) == {"$ref": f"#/components/schemas/{model.SCHEMA}"}, path
