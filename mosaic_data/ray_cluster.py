"""Ray as the engine of ``--executor ray``: connecting to a cluster (or starting a local one), resource requests,
and Ray's errors as one line each.

Collection and evaluation hand Ray the very units of work their local executors run (a shard, an episode), with
the same seeds, so the results do not depend on the executor. Ray retries a unit whose worker process died
(``kill -9``, the out-of-memory killer, a lost node); a unit's output is committed atomically, so a retried one is
never written twice.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

EXECUTORS = ("local", "ray")
MAX_RETRIES = 3
"""Ray retries of a unit whose worker died (system failures only: a bug in the unit is reported, not retried)."""
GIB = 1024**3


@dataclass(frozen=True)
class WorkerResources:
    """What one worker asks of the cluster, so that Ray packs workers onto nodes without overcommitting memory."""

    num_cpus: float
    memory_gb: float

    def options(self) -> dict[str, Any]:
        return {"num_cpus": self.num_cpus, "memory": int(self.memory_gb * GIB)}


_session_is_ours = False
"""True while :func:`ray_session` holds a Ray it started or connected itself: leaving it then ends this job, and
Ray kills the job's worker processes with it."""


class RayExecutorError(ValueError):
    """Ray could not run the work (not installed, cluster unreachable, no shared folder); the message names the fix."""


@contextmanager
def ray_session(address: str | None, num_cpus: int | None = None) -> Iterator[Any]:
    """Connect to the cluster at ``address`` or, without one, start a local Ray on this machine's cores; disconnect
    (and stop the local Ray) afterwards, Ctrl-C and errors included. Yields the ``ray`` module."""
    try:
        import ray
    except ImportError:
        raise RayExecutorError("--executor ray needs Ray: pip install 'ray==2.60.0' (or reinstall mosaic)") from None
    if ray.is_initialized():  # a caller (a notebook, a test) already connected: use that session, leave it open
        yield ray
        return
    settings: dict[str, Any] = {"logging_level": "ERROR", "log_to_driver": False}
    if address is None:
        # "local": a new Ray of this command's own, even when `ray start` left a cluster on this machine
        settings |= {"address": "local", "num_cpus": num_cpus or os.cpu_count() or 1, "include_dashboard": False}
    else:
        settings["address"] = address
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")  # a local, single-user Ray: no token to manage
    unreachable = _unreachable(address) if address is not None else None
    try:
        if unreachable is not None:  # ray.init would retry for many minutes before it gives up
            raise ConnectionError(unreachable)
        ray.init(**settings)
    except ConnectionError as error:
        raise RayExecutorError(
            f"cannot reach a Ray cluster at --ray-address {address} ({(str(error).splitlines() or ['no answer'])[0]}): "
            "start one with `ray start --head` on the head node, or leave --ray-address out to run Ray on this machine"
        ) from None
    global _session_is_ours
    _session_is_ours = True
    try:
        yield ray
    finally:
        _session_is_ours = False
        ray.shutdown()


def _unreachable(address: str, timeout_s: float = 5.0) -> str | None:
    """Why nothing answers at a ``host:port`` (or ``ray://host:port``) address, or None when something does; 'auto'
    and other forms are left to Ray, which fails fast on them."""
    import socket

    host_port = address.removeprefix("ray://")
    host, _, port = host_port.rpartition(":")
    if not host or not port.isdigit():
        return None
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as error:
        return f"no answer on port {port}: {error.strerror or error}"
    return None


def cluster_cpus(ray: Any) -> int:
    """Logical CPUs of the whole cluster (what ``--workers`` defaults to under Ray)."""
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def worker_env(ray: Any, threads: int, extra: dict[str, str] | None = None) -> dict[str, Any]:
    """A ``runtime_env`` whose processes render and run BLAS on ``threads`` threads (the CPUs Ray gives each worker)
    and render headless, as the local executors' worker processes do."""
    threads_text = str(max(1, int(threads)))
    env_vars = {
        "LP_NUM_THREADS": threads_text,
        "OMP_NUM_THREADS": threads_text,
        "MKL_NUM_THREADS": threads_text,
        "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"),
        "HF_HUB_OFFLINE": os.environ.get("HF_HUB_OFFLINE", "1"),
    } | (extra or {})
    return {"env_vars": env_vars}


def check_shared_folder(ray: Any, folder: Path, resources: WorkerResources) -> None:
    """Fail early, with the fix, when a worker on another node cannot see ``folder``: shards and results are written
    where the driver reads them, so ``folder`` must be on a filesystem every node mounts at the same path."""
    import uuid

    marker = folder / f".ray-probe-{uuid.uuid4().hex}"
    marker.write_text("mosaic")
    try:
        probe = ray.remote(_sees_file)
        nodes = [node for node in ray.nodes() if node.get("Alive") and node.get("Resources", {}).get("CPU", 0) >= resources.num_cpus]
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        checks = [
            probe.options(num_cpus=0, scheduling_strategy=NodeAffinitySchedulingStrategy(node["NodeID"], soft=False)).remote(str(marker))
            for node in nodes
        ]
        for node, (seen, host) in zip(nodes, ray.get(checks)):
            if not seen:
                raise RayExecutorError(
                    f"Ray node {host} ({node.get('NodeManagerAddress')}) cannot see {folder}: put --output-dir on a "
                    "filesystem every node mounts at the same path (NFS, Lustre, ...)"
                )
    finally:
        marker.unlink(missing_ok=True)


def _sees_file(path: str) -> tuple[bool, str]:
    import socket

    return os.path.exists(path), socket.gethostname()


def task_error_line(error: BaseException, what: str) -> str:
    """One line for a failed unit: the worker's own exception message, not Ray's wrapped traceback."""
    import ray.exceptions as ray_errors

    if isinstance(error, ray_errors.RayTaskError):
        cause = error.cause if getattr(error, "cause", None) is not None else error
        text = str(cause).strip().splitlines()
        message = text[-1] if text else type(cause).__name__
        if isinstance(cause, (ray_errors.WorkerCrashedError, ray_errors.NodeDiedError)):
            message = f"its Ray worker died {MAX_RETRIES + 1} times ({type(cause).__name__})"
        return f"{what} failed on Ray: {message}"
    if isinstance(error, (ray_errors.WorkerCrashedError, ray_errors.NodeDiedError, ray_errors.OutOfMemoryError)):
        return f"{what} failed on Ray: its worker died {MAX_RETRIES + 1} times ({type(error).__name__}, e.g. out of memory)"
    return f"{what} failed on Ray: {(str(error).strip().splitlines() or [type(error).__name__])[-1]}"


def stop_tasks(ray: Any, refs: list) -> None:
    """Stop every unit still running (Ctrl-C, an error): their processes are killed, nothing half-written stays.

    In a session of :func:`ray_session`'s own, leaving the session ends the job and Ray kills its workers, so nothing
    is cancelled here: a forced cancel racing with a unit that is just completing aborts the driver inside Ray
    (``Check failed: it != submissible_tasks_.end()``, ray-project/ray#54846) instead of exiting with Ctrl-C's 130.
    A session of the caller's (a notebook) stays open, so its units are cancelled."""
    if _session_is_ours:
        return
    for ref in refs:
        try:
            ray.cancel(ref, force=True)
        except Exception:  # already finished, or the cluster is going away
            pass

