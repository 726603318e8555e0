"""A daemon thread that runs one call at a time: how policy calls get a deadline.

Python cannot stop a running thread, so a call that overruns its deadline is
abandoned: the caller gets :class:`CallTimeout` at once, the thread is marked
stuck and refuses further calls, and because it is a daemon it never keeps the
process alive (unlike ``concurrent.futures`` workers, which are joined at exit).
"""

from __future__ import annotations

import asyncio
import queue
import threading
from collections.abc import Callable
from typing import Any


class CallTimeout(Exception):
    """A call did not return within its timeout (it may still be running)."""


class _Job:
    __slots__ = ("fn", "args", "done", "result", "error", "notify")

    def __init__(self, fn: Callable[..., Any], args: tuple[Any, ...], notify: Callable[[_Job], object] | None = None) -> None:
        self.fn, self.args, self.notify = fn, args, notify
        self.done = threading.Event()
        self.result: Any = None
        self.error: BaseException | None = None


class WorkerThread:
    """Runs calls sequentially on one daemon thread; see the module docstring."""

    def __init__(self, name: str = "dyana-policy") -> None:
        self._jobs: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()
        self.stuck = False

    def _run(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None:
                return
            try:
                job.result = job.fn(*job.args)
            except BaseException as exc:  # handed to the caller, whatever it is
                job.error = exc
            job.done.set()
            if job.notify is not None:
                try:
                    job.notify(job)
                except RuntimeError:  # the waiting event loop is gone
                    pass

    def _submit(self, job: _Job) -> None:
        if self.stuck:
            raise CallTimeout("the worker thread is still busy with a call that overran its deadline")
        self._jobs.put(job)

    def call(self, fn: Callable[..., Any], *args: Any, timeout: float | None = None) -> Any:
        """``fn(*args)`` on the thread; its result or exception, or CallTimeout after ``timeout`` s."""
        job = _Job(fn, args)
        self._submit(job)
        if not job.done.wait(timeout):
            self.stuck = True
            raise CallTimeout(f"no return within {timeout} s")
        if job.error is not None:
            raise job.error
        return job.result

    async def acall(self, fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)`` on the thread, awaited from an event loop without blocking it."""
        loop = asyncio.get_running_loop()
        future = loop.create_future()

        def settle(job: _Job) -> None:
            if not future.done():
                if job.error is not None:
                    future.set_exception(job.error)
                else:
                    future.set_result(job.result)

        self._submit(_Job(fn, args, lambda job: loop.call_soon_threadsafe(settle, job)))
        return await future

    def close(self) -> None:
        """Let the thread end after its current call (returns at once)."""
        self._jobs.put(None)
