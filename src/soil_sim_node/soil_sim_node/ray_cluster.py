"""Fan work out as Ray tasks: on the user's Ray cluster, or on a private loopback-only instance.

Ray is the user's cluster, not ours: given an ADDRESS we connect a driver, submit tasks and
disconnect at the end; the cluster keeps running. Given ``LOCAL`` we start a Ray instance for
this process only, bound to 127.0.0.1 with usage statistics off, and stop it at the end.
Ray is imported here, on first use only: the rest of the project never pays its import time.

Tasks run once (``max_retries=0``): a task that fails, or whose worker or node dies, is
reported by ``run_tasks`` in its result slot and never re-run behind the caller's back (a re-run
would meet the files its first attempt wrote).
"""
from __future__ import annotations

import argparse
import os
import socket
import sys
from contextlib import contextmanager

_NO_CLUSTER = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
LOCAL = "local"  # the --ray value (and Ray's own address) for "start a local instance"
RAY_OPTION_HELP = (
    "run on Ray: without ADDRESS on a local Ray instance of --workers CPUs bound to 127.0.0.1 (started and "
    "stopped here); with ADDRESS (e.g. 10.0.0.5:6379, as printed by `ray start --head`) as tasks on that running "
    "cluster, which is left running (a cluster with token authentication, Ray's default, also needs "
    "RAY_AUTH_MODE=token and its token). Every Ray node needs this project installed, and the bag directories "
    "on shared storage at the same path")


def add_ray_option(parser, what: str) -> None:
    """``--ray [ADDRESS]`` for every CLI that can fan out over Ray (one wording everywhere)."""
    parser.add_argument("--ray", nargs="?", const=LOCAL, metavar="ADDRESS", type=_ray_address,
                        help=f"{what}: {RAY_OPTION_HELP}")


def _ray_address(text: str) -> str:
    """An ADDRESS given to --ray; an empty one (``--ray ''``, a shell variable left unset) had run
    the local pool without a word."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"{text!r} is no address: give host:port, auto, or --ray alone for a "
                                         "local instance")
    return text.strip()


@contextmanager
def ray_session(address: str, num_cpus: int | None = None):
    """Yield the ``ray`` module connected to ``address`` (``LOCAL``: a new loopback-only
    instance of ``num_cpus`` CPUs). A session the caller already opened is used as it is and
    left open. ValueError names an address that cannot be reached."""
    if not address:
        raise ValueError(f"Ray address={address!r} must be {LOCAL!r} or host:port")
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    local = address == LOCAL
    if local and "ray" not in sys.modules:
        # Ray resolves 127.0.0.1 to the machine's routable address unless "clusters" are off
        # (read once, at import); with them off every process of the instance binds to loopback.
        previous = os.environ.get(_NO_CLUSTER)
        os.environ[_NO_CLUSTER] = "0"
        try:
            import ray  # noqa: F401
        finally:
            if previous is None:
                del os.environ[_NO_CLUSTER]
            else:
                os.environ[_NO_CLUSTER] = previous
    import ray
    from ray._private import ray_constants

    if ray.is_initialized():
        yield ray
        return
    if not local:
        _check_reachable(address)
    if local and ray_constants.ENABLE_RAY_CLUSTER:
        raise RuntimeError("ray was imported in this process before a local instance was asked for; it would "
                           "not be bound to loopback only: use --ray from a fresh process")
    try:
        if local:
            ray.init(address=LOCAL, num_cpus=num_cpus, include_dashboard=False, _node_ip_address="127.0.0.1",
                     logging_level="warning")
        else:
            ray.init(address=address, logging_level="warning")
    except ray.exceptions.AuthenticationError as err:
        raise ValueError(f"cannot connect to the Ray cluster at --ray={address!r}: {err} (a cluster started with "
                         "token authentication needs RAY_AUTH_MODE=token here, and its token)") from None
    except (ConnectionError, ValueError) as err:
        raise ValueError(f"cannot connect to the Ray cluster at --ray={address!r}: {err}") from None
    try:
        yield ray
    finally:
        ray.shutdown()  # a local instance stops; a cluster only loses this driver


def _check_reachable(address: str, timeout_s: float = 10.0) -> None:
    """ValueError if nothing listens at a host:port address, or at the one ``auto`` stands for:
    Ray itself would retry forever (``auto`` read a stale address a cluster stopped long ago had
    left in Ray's temp directory, and a run ignored SIGTERM for 40 s)."""
    target = _auto_address() if address == "auto" else address
    host, sep, port = target.rpartition(":")
    if target.startswith("ray://") or not sep or not port.isdigit():
        return  # Ray's client form (ray://): Ray checks it
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as err:
        via = (f" (where --ray='auto' points: RAY_ADDRESS or the last cluster started on this machine), {target}"
               if target != address else "")
        raise ValueError(f"cannot reach the Ray cluster at --ray={address!r}{via}: {err}") from None


def _auto_address() -> str:
    """The host:port Ray connects to for ``auto``: RAY_ADDRESS, else the address the last
    ``ray start`` on this machine wrote to Ray's temp directory. ValueError if there is none."""
    from ray._private.services import get_ray_address_from_environment

    try:
        return str(get_ray_address_from_environment("auto", None))
    except (ConnectionError, ValueError, OSError) as err:
        raise ValueError(f"--ray='auto' finds no Ray cluster on this machine: {err}") from None


def cluster_cpus() -> int:
    """CPUs of the connected Ray cluster (at least 1)."""
    import ray

    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def run_tasks(fn, jobs: list, on_done=None) -> list:
    """``fn(job)`` as one Ray task per job, inside a ``ray_session``; returns the results in
    job order. A task that raised gives its exception in its slot (the original one, not Ray's
    wrapper); one whose worker or node died gives Ray's error. ``on_done(result)`` is called
    as each task finishes (progress)."""
    import ray

    remote = ray.remote(max_retries=0)(fn)
    refs = [remote.remote(job) for job in jobs]
    slot = {ref: i for i, ref in enumerate(refs)}
    out: list = [None] * len(refs)
    pending = refs
    while pending:
        done, pending = ray.wait(pending, num_returns=1)
        for ref in done:
            try:
                result = ray.get(ref)
            except ray.exceptions.RayTaskError as err:
                result = err.cause if isinstance(err.cause, Exception) else err
            except ray.exceptions.RayError as err:
                result = err
            out[slot[ref]] = result
            if on_done is not None:
                on_done(result)
    return out
