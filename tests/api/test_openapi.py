"""The OpenAPI page documents every error as the one problem+json shape, with an example, and
the README's errors table names every problem type the service can answer."""

import re
from pathlib import Path

from app.api.problems import EXAMPLES, FRAMEWORK_PROBLEMS
from app.geometry.errors import GeometryError
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


def _subclasses(cls: type) -> set[type]:
    return {cls} | {grand for sub in cls.__subclasses__() for grand in _subclasses(sub)}


def test_the_readme_errors_table_names_every_problem_type():
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    table = readme[readme.index("### Errors") : readme.index("## Configuration")]
    listed = set(re.findall(r"^\| \d{3} \| `([a-z-]+)` \|", table, re.MULTILINE))
    raised = {error.slug for error in _subclasses(GeometryError)}
    documented = {slug for examples in EXAMPLES.values() for slug, _, _ in examples}
    framework = {slug for status, (slug, _) in FRAMEWORK_PROBLEMS.items() if status == 400}
    assert raised | documented | framework <= listed, sorted((raised | documented | framework) - listed)
