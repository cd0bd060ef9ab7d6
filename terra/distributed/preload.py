"""Dask worker preload for the local clusters Terra starts (`--workers`): ignore SIGINT.

Ctrl-C in a terminal sends SIGINT to every process of the foreground group, the worker processes
included. The `terra map` client handles it (it stops the cluster and leaves its checkpoint); workers
that also handled it would each print a KeyboardInterrupt traceback while being shut down.
"""

from __future__ import annotations

import signal
import threading


def dask_setup(worker) -> None:  # noqa: ARG001 (Dask's preload signature)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
