"""One function call on a second thread, its result (or its exception) taken later.

numpy's and scipy.ndimage's loops release the GIL, so two independent numeric stages overlap on
two cores (the ground layers of a build beside its terrain grid). The thread is a daemon: Ctrl-C
in the main thread ends the command at once, without waiting for the call to finish.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from typing import Any, Generic, TypeVar

T = TypeVar("T")


class Background(Generic[T]):
    """`function(*args)` started on a daemon thread now; `result()` waits for it and returns its
    value, or raises what it raised."""

    def __init__(self, function: Callable[..., T], *args: Any, name: str = "terra-background") -> None:
        self._value: T | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(function, args), name=name, daemon=True)
        self._thread.start()

    def _run(self, function: Callable[..., T], args: tuple[Any, ...]) -> None:
        try:
            self._value = function(*args)
        except BaseException as exc:  # handed to result(), raised in the caller's thread
            self._error = exc

    def result(self) -> T:
        """The call's value once it has finished; its exception, raised here, if it failed."""
        self._thread.join()
        if self._error is not None:
            error, self._error = self._error, None  # no cycle through the traceback kept alive
            raise error
        return self._value  # type: ignore[return-value]  # set: the call returned


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity where the system tells it)."""
    affinity = getattr(os, "sched_getaffinity", None)
    return len(affinity(0)) if affinity is not None else (os.cpu_count() or 1)
