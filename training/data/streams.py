"""The named random streams of a build: every draw comes from one, so that adding a kind of row
never moves the rows of another.

A stream is NumPy's seed sequence of the build seed and its words: ``[seed, word]`` for the
serial stages, ``[seed, chunk, word]`` for the parallel tasks (each chunk its own stream, so a
chunk is the same whichever worker draws it and in whatever order). Anny's pose draws
(:mod:`training.data.bodies`) use ``[seed, group, identity]``.

Known overlaps, kept because changing a word redraws the rows it feeds and with them every
committed table (give every stream its own words at the next full rebuild, e.g. a leading kind
word before the chunk):

- "candidate" and "triple" chunks share word 1: a candidate chunk's first draw may repeat the
  union of the same chunk's first triple. Harmless: candidates are only offered as Test B union
  types, and one that equals a triple's union has IoU 1 with a seen union, so the novelty filter
  (IoU < 0.8 with every training and triple union) always drops it.
- NumPy's seed sequence ignores trailing zero words, so a "pair" chunk ``[seed, c, 0]`` is the
  serial stream ``[seed, c]``: pair chunks 2–8 draw the numbers of the serial streams (chunk 2
  draws its regions with the numbers "splits" assigns rows to bodies with).
- ``[seed, chunk, word]`` and anny's ``[seed, group, identity]`` coincide where chunk = group
  and word = identity (pair chunk 0 and the first known man's poses; session chunk 0 and the
  tenth known man's).

In each case the same numbers serve unrelated draws (regions on the template against bodies,
poses or camera positions), so no measured figure depends on it; but they are not independent
by design. ``tests/training/data/test_streams.py`` holds the list to exactly these.
"""

import numpy as np

SERIAL = {"splits": 2, "test_b": 3, "retrieval": 4, "overlap": 5, "derived": 6, "sessions": 7, "session_plan": 8}
CHUNKED = {"pair": 0, "candidate": 1, "triple": 1, "retrieval": 2, "overlap": 3, "session": 9}
# Serial streams added since the overlaps above were found: ``[seed, LATER_FAMILY, word]``, a
# family word no chunk number or anny group reaches, and no word 0 (it would be dropped).
LATER_FAMILY = 2**32 - 1
LATER = {"remeshed_train": 1}


def serial_stream(seed: int, name: str) -> np.random.Generator:
    """The stream of a serial stage (a key of :data:`SERIAL` or :data:`LATER`)."""
    if name in LATER:
        return np.random.default_rng([seed, LATER_FAMILY, LATER[name]])
    return np.random.default_rng([seed, SERIAL[name]])


def chunk_stream(seed: int, name: str, chunk: int) -> np.random.Generator:
    """The stream of one parallel chunk of a kind (a key of :data:`CHUNKED`)."""
    return np.random.default_rng([seed, chunk, CHUNKED[name]])
