"""The OpenAPI page documents every error as the one problem+json shape, with an example."""

from app.main import create_app


def test_every_documented_error_is_a_problem_with_an_example():
    schema = create_app().openapi()
    checked = 0
    for path, operations in schema["paths"].items():
        for method, operation in operations.items():
            for status, response in operation["responses"].items():
                if status.startswith("2") or path in ("/healthz", "/readyz"):
                    continue
                content = response["content"]
                assert list(content) == ["application/problem+json"], (method, path, status)
                examples = content["application/problem+json"]["examples"]
                assert examples, (method, path, status)
                assert all(e["value"]["status"] == int(status) for e in examples.values())
                checked += 1
    assert checked >= 20
