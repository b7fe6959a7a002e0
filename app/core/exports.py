"""A package's public names, imported when first asked for.

``training`` takes what it needs from ``app`` through the packages' public names (``from
app.geometry import Mesh``), never from their modules, so that the service can move code between
its modules without breaking the training side. The names are resolved lazily (a module
``__getattr__``, PEP 562): importing one module of a package does not import the others (a solver
worker loads only what it solves with), and ``app.inference`` and ``app.sessions``, whose modules
import each other's, stay free of import cycles.
"""

import importlib
from collections.abc import Callable


def lazy_exports(package: str, modules: dict[str, tuple[str, ...]]) -> tuple[list[str], Callable[[str], object]]:
    """``package``'s public names (``modules``: each of its modules and the names it gives out)
    and the module ``__getattr__`` that imports a name's module the first time it is asked for."""
    home = {name: f"{package}.{module}" for module, names in modules.items() for name in names}

    def attribute(name: str) -> object:
        if name not in home:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(home[name]), name)

    return sorted(home), attribute
