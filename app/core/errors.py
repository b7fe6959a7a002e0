"""The base of every error that is the client's input's fault.

Each subclass carries a stable ``slug`` that the API turns into a problem ``type`` and a
``title``; the HTTP status belongs to the API layer. Geometry (a file that is no shape), spectra
(a vector that is no spectrum) and the solver pool (a shape too costly to solve) each raise
their own subclasses, none of them the others' base.
"""


class InputError(ValueError):
    """Base class: the request's input cannot be used, and the reason is the caller's."""

    slug = "invalid-request"
    title = "Invalid request"
