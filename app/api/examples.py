"""Success examples for the OpenAPI page: answers recorded from the README's samples.

``examples.json`` holds what the service answered for ``spectral-unions samples`` (the two
parts, the body) on this repository's models, numbers rounded to three decimals and the
localized vertex list cut to five; ``tests/api/test_openapi.py`` validates each against the
response model its route declares, so an example cannot drift from the schema unnoticed.
"""

import json
from functools import cache
from pathlib import Path

EXAMPLES_FILE = Path(__file__).with_name("examples.json")


@cache
def _recorded() -> dict[str, dict]:
    return json.loads(EXAMPLES_FILE.read_text())


def success(name: str, status: int = 200) -> dict[int | str, dict]:
    """An OpenAPI ``responses=`` entry: the JSON example of route ``name``'s success (none until
    ``benchmarks/readme_examples.py`` has recorded one: the OpenAPI test says which are missing)."""
    recorded = _recorded().get(name)
    return {status: {"content": {"application/json": {} if recorded is None else {"example": recorded}}}}
