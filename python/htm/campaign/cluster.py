"""Campaign chunks on a Dask distributed cluster (`htm campaign --cluster tcp://HOST:PORT`).

Each chunk is one task calling `engine.run_chunk` on a worker, which must have this htm installed
(the same environment, or the same version). A worker that dies mid-chunk loses only that chunk:
the scheduler hands it to another worker (up to its `allowed-failures`), and `retries` covers a
chunk that raised. Results come back as they finish; the driver writes them to the store.
"""
from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

from htm.campaign.engine import Chunk, run_chunk
from htm.errors import HtmError

CONNECT_TIMEOUT_S = 5
WORKERS_TIMEOUT_S = 30
RETRIES = 3


class ClusterError(HtmError):
    """The Dask scheduler cannot be reached or has no workers."""


def default_address() -> str | None:
    """The cluster `--cluster` defaults to: $HTM_CLUSTER, else none (this machine)."""
    return os.environ.get("HTM_CLUSTER") or None


def connect(address: str) -> Any:
    """A Dask client on the scheduler at `address`, with at least one worker (raises ClusterError)."""
    import logging

    from distributed import Client

    if not address.startswith(("tcp://", "tls://", "inproc://", "ucx://")):
        raise ClusterError(f"--cluster {address}: give the scheduler's address as tcp://HOST:PORT")
    # distributed logs a traceback of every failed connection attempt; the one-line error below says it
    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    try:
        client = Client(address, timeout=f"{CONNECT_TIMEOUT_S}s", set_as_default=False)
    except (OSError, TimeoutError) as e:
        raise ClusterError(f"cannot reach the Dask scheduler at {address} ({type(e).__name__}: "
                           f"{' '.join(str(e).split())[:200]}); nothing was run") from None
    logging.getLogger("distributed").setLevel(logging.WARNING)
    try:
        client.wait_for_workers(1, timeout=WORKERS_TIMEOUT_S)
    except (OSError, TimeoutError):
        client.close()
        raise ClusterError(f"the Dask scheduler at {address} has no worker after {WORKERS_TIMEOUT_S} s; nothing was run") from None
    return client


def runner(client: Any, workers: list[str] | None = None):
    """Chunks as Dask tasks (optionally only on `workers`); results yielded as they finish."""
    from distributed import as_completed

    def run(chunks: list[Chunk], mode: str) -> Iterator[list[dict[str, Any]]]:
        # threads = 1 per task: the cluster's parallelism is its workers' threads, one test each
        pin = {"workers": workers, "allow_other_workers": False} if workers else {}
        futs = [client.submit(run_chunk, ch, mode, 1, pure=False, retries=RETRIES, **pin) for ch in chunks]
        try:
            for f in as_completed(futs, loop=client.loop):
                yield f.result()
        finally:
            for f in futs:
                f.cancel()

    return run
