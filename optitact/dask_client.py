"""A Dask distributed client from a scheduler address or a client (the ``dask`` extra)."""

from __future__ import annotations

from contextlib import contextmanager

from optitact._optional import require


@contextmanager
def dask_client(scheduler, *, purpose: str):
    """Yield a ``distributed.Client``: ``scheduler`` itself, or one connected to that address (closed after).

    Raises
    ------
    TypeError
        ``scheduler`` is neither an address string nor a ``distributed.Client``.
    MissingExtraError
        Dask distributed is not installed.
    """
    distributed = require("distributed", purpose=purpose)
    own = not isinstance(scheduler, distributed.Client)
    if own and not isinstance(scheduler, str):
        raise TypeError(f"scheduler must be an address string or a distributed.Client, got "
                        f"{type(scheduler).__name__}")
    client = distributed.Client(scheduler) if own else scheduler
    try:
        yield client
    finally:
        if own:
            client.close()
