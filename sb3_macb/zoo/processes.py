"""Train packs in worker processes (one thread each), as the study scripts do: spawned, ended with their parent."""

import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any


def _watch_parent() -> None:
    """End this process when the process that started it is gone (a killed script's workers would otherwise run on)."""
    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


def _call(function: Callable[..., tuple[str, bool]], arguments: Sequence[Any]) -> tuple[str, bool]:
    _watch_parent()
    return function(*arguments)


def run_packs(function: Callable[..., tuple[str, bool]], jobs: Sequence[Sequence[Any]], n_processes: int = 1) -> int:
    """
    Call ``function(*arguments)`` for each entry of ``jobs`` in ``n_processes`` spawned worker processes, printing
    the line each returns in the order of ``jobs``.

    :param function: A module-level function (it is pickled) returning (a line to print, whether it failed).
    :param jobs: The arguments of each call.
    :param n_processes: Worker processes at a time.
    :return: The number of calls that failed.
    """
    failed = 0
    with ProcessPoolExecutor(n_processes, mp_context=get_context("spawn")) as pool:
        futures = [pool.submit(_call, function, arguments) for arguments in jobs]
        for future in futures:
            line, error = future.result()
            failed += error
            print(line, flush=True)
    return failed
