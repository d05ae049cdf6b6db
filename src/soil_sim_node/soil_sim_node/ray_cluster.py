"""Fan work out as Ray tasks: on the user's Ray cluster, or on a private loopback-only instance.

Ray is the user's cluster, not ours: given an ADDRESS we connect a driver, submit tasks and
disconnect at the end; the cluster keeps running. Given ``LOCAL`` we start a Ray instance for
this process only, bound to 127.0.0.1 with usage statistics off, and stop it at the end.
Ray is imported here, on first use only: the rest of the project never pays its import time.

Tasks run once (``max_retries=0``): a task that fails, or whose worker or node dies, is
reported by ``run_tasks`` in its result slot and never re-run behind the caller's back (a re-run
would meet the files its first attempt wrote). A cluster whose head stops answering is given up
after CLUSTER_LOST_AFTER_S: Ray's driver neither fails nor finishes the tasks it was waiting for,
and aborts the whole process after 60 s of it (a C++ abort: no Python ``finally`` runs, nothing
is said about the work), so the caller gets its unfinished tasks as ``ClusterLost`` in time to
say what was done.
"""
from __future__ import annotations

import argparse
import ipaddress
import os
import signal
import socket
import sys
import threading
import time
from contextlib import contextmanager

_NO_CLUSTER = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
# How long the cluster's head (its GCS port) may refuse connections before its unfinished tasks
# are given up [s]: under Ray's own 60 s (gcs_rpc_server_reconnect_timeout_s), after which it
# aborts the process, with room for the driver's shutdown (~5 s against a dead head)
CLUSTER_LOST_AFTER_S = 20.0
# The most a user may give the head (``--ray-give-up-after``) [s]: Ray's driver aborts at 60 s
CLUSTER_LOST_MAX_S = 50.0
_WAIT_POLL_S = 2.0  # how often a wait with nothing finished checks the head [s]
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
    parser.add_argument("--ray-give-up-after", type=_give_up_after, default=None, metavar="S",
                        help="with --ray: seconds the cluster's head may refuse connections before the unfinished "
                             f"tasks are given up and said (default {CLUSTER_LOST_AFTER_S:g}; at most "
                             f"{CLUSTER_LOST_MAX_S:g}: Ray's driver aborts the process at 60 s)")


def parse_ray_options(parser, argv) -> argparse.Namespace:
    """``parser.parse_args(argv)`` with ``add_ray_option``'s options checked together:
    --ray-give-up-after without --ray is refused (it was ignored in silence, an outside tester's),
    and its default is filled in."""
    args = parser.parse_args(argv)
    if args.ray is None and args.ray_give_up_after is not None:
        parser.error(f"--ray-give-up-after {args.ray_give_up_after:g} is for a run on Ray: give --ray too, or leave it out")
    if args.ray_give_up_after is None:
        args.ray_give_up_after = CLUSTER_LOST_AFTER_S
    return args


def _give_up_after(text: str) -> float:
    """--ray-give-up-after S: a number of seconds in (0, CLUSTER_LOST_MAX_S]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not 0.0 < value <= CLUSTER_LOST_MAX_S:  # NaN fails too
        raise argparse.ArgumentTypeError(f"{text} s is not in (0, {CLUSTER_LOST_MAX_S:g}] s: Ray's driver aborts "
                                         "the process after 60 s without its head")
    return value


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
    clusters = ray_constants.ENABLE_RAY_CLUSTER
    if not local and _loopback_only(address):
        # the driver is this process alone: the one place Ray reads the flag after import (the
        # node's own address) is told what the cluster was started with
        ray_constants.ENABLE_RAY_CLUSTER = False
    # ray.init takes SIGTERM over (a handler that exits at once, and its core worker's crash
    # reporter): a SIGTERM then left unfinished bags and workers finishing them after the driver
    # died. The caller's handler (``interrupts.terminate_as_interrupt``: a clean stop) is put back.
    main_thread = threading.current_thread() is threading.main_thread()
    sigterm = signal.getsignal(signal.SIGTERM) if main_thread else None
    try:
        if local:
            ray.init(address=LOCAL, num_cpus=num_cpus, include_dashboard=False, _node_ip_address="127.0.0.1",
                     logging_level="warning")
        else:
            ray.init(address=address, logging_level="warning")
        if sigterm is not None:
            signal.signal(signal.SIGTERM, sigterm)
    except ray.exceptions.AuthenticationError as err:
        raise ValueError(f"cannot connect to the Ray cluster at --ray={address!r}: {err} (a cluster started with "
                         "token authentication needs RAY_AUTH_MODE=token here, and its token)") from None
    except (ConnectionError, ValueError) as err:
        # (a cluster with token authentication refuses a driver without RAY_AUTH_MODE=token this way too:
        # only Ray's own log lines said "InvalidAuthToken")
        hint = ("" if local or os.environ.get("RAY_AUTH_MODE") == "token" else
                "; if the cluster was started with token authentication, set RAY_AUTH_MODE=token and its token here")
        raise ValueError(f"cannot connect to the Ray cluster at --ray={address!r}: {err}{hint}") from None
    finally:
        if not ray.is_initialized():
            ray_constants.ENABLE_RAY_CLUSTER = clusters
    try:
        yield ray
    finally:
        ray.shutdown()  # a local instance stops; a cluster only loses this driver
        ray_constants.ENABLE_RAY_CLUSTER = clusters
        if sigterm is not None:  # (the shutdown resets the process's SIGTERM action beneath Python's record)
            signal.signal(signal.SIGTERM, sigterm)


def _check_reachable(address: str, timeout_s: float = 10.0) -> None:
    """ValueError if nothing listens at a host:port address, or at the one ``auto`` stands for, or
    what listens there is no gRPC server (``_grpc_problem``): Ray itself would retry forever
    (``auto`` read a stale address a cluster stopped long ago had left in Ray's temp directory,
    and a run ignored SIGTERM for 40 s)."""
    hp = _host_port(address)
    if hp is None:
        return  # Ray's client form (ray://): Ray checks it
    target = f"{hp[0]}:{hp[1]}"
    via = (f" (where --ray='auto' points: RAY_ADDRESS or the last cluster started on this machine), {target}"
           if address == "auto" else "")
    err = _connect_error(hp, timeout_s)
    if err is not None:
        raise ValueError(f"cannot reach the Ray cluster at --ray={address!r}{via}: {err}") from None
    if os.environ.get("RAY_USE_TLS", "0").lower() in ("0", "false", ""):  # (a TLS head waits for a TLS hello)
        problem = _grpc_problem(hp, timeout_s)
        if problem is not None:
            raise ValueError(f"no Ray head answers at --ray={address!r}{via}: something listens there but {problem} "
                             "(a Ray head's GCS port speaks gRPC; is it another service's port, e.g. the dashboard's?)")


def _host_port(address: str) -> tuple[str, int] | None:
    """(host, port) of a host:port address (``auto`` resolved); None for Ray's client form."""
    target = _auto_address() if address == "auto" else address
    host, sep, port = target.rpartition(":")
    if target.startswith("ray://") or not sep or not port.isdigit():
        return None
    return host.strip("[]"), int(port)


def _loopback_only(address: str, timeout_s: float = 2.0) -> bool:
    """True if ``address`` is a loopback host:port whose port answers on loopback but not on
    the address Ray would put in its place: a head started with RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0
    (it listens on 127.0.0.1 alone). Ray's driver would dial the machine's routable address for
    ever ("Failed to connect to GCS at 192.0.2.2"); it has to run with clusters off, like the head."""
    hp = _host_port(address)
    if hp is None or not _is_loopback(hp[0]):
        return False
    routable = _routable_ip()
    if routable is None or _is_loopback(routable):
        return False
    return _connect_error((routable, hp[1]), timeout_s) is not None


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(socket.gethostbyname(host) if host == "localhost" else host).is_loopback
    except (ValueError, OSError):
        return False


def _routable_ip() -> str | None:
    """The address this machine's traffic leaves from, found the way Ray finds it (a UDP socket
    "connected" to a public address: no packet is sent); None without a route."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(("8.8.8.8", 80))
            return s.getsockname()[0]
        except OSError:
            return None


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


class ClusterLost(ConnectionError):
    """The Ray cluster's head stopped answering while tasks were unfinished."""


def run_tasks(fn, jobs: list, on_done=None, lost_after_s: float = CLUSTER_LOST_AFTER_S) -> list:
    """``fn(job)`` as one Ray task per job, inside a ``ray_session``; returns the results in
    job order. A task that raised gives its exception in its slot (the original one, not Ray's
    wrapper); one whose worker or node died gives Ray's error; every task unfinished when the
    head has refused connections for ``lost_after_s`` gives ``ClusterLost``. ``on_done(result)``
    is called as each task finishes (progress)."""
    import ray

    remote = ray.remote(max_retries=0)(fn)
    refs = [remote.remote(job) for job in jobs]
    slot = {ref: i for i, ref in enumerate(refs)}
    out: list = [None] * len(refs)
    pending = refs
    try:
        head = _host_port(ray.get_runtime_context().gcs_address)
    except (AttributeError, RuntimeError, ValueError):  # a Ray client session (ray://) has no head to watch
        head = None
    silent_since: float | None = None  # when the head first refused a connection, of the current spell
    while pending:
        done, pending = ray.wait(pending, num_returns=1, timeout=_WAIT_POLL_S)
        if not done:
            if head is None or _connect_error(head) is None:
                silent_since = None
                continue
            silent_since = time.monotonic() if silent_since is None else silent_since
            if time.monotonic() - silent_since >= lost_after_s:
                lost = ClusterLost(f"the Ray cluster's head at {head[0]}:{head[1]} has refused connections for "
                                   f"{lost_after_s:g} s")
                for ref in pending:
                    out[slot[ref]] = lost
                break
            continue
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


# HTTP/2's client connection preface and an empty SETTINGS frame: a gRPC server (a Ray head's GCS)
# answers with a SETTINGS frame of its own (frame type 4 in the fourth byte)
_H2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])


def _grpc_problem(host_port: tuple[str, int], timeout_s: float) -> str | None:
    """Why what listens at ``host_port`` is no gRPC server; None if it answers as one. Why: Ray's
    driver pointed at a port where another service listens (an HTTP server, the dashboard) retried
    "Failed to get cluster ID from GCS server" for ever."""
    try:
        with socket.create_connection(host_port, timeout=timeout_s) as sock:
            sock.sendall(_H2_PREFACE)
            answer = b""
            while len(answer) < 9:
                chunk = sock.recv(9 - len(answer))
                if not chunk:
                    break
                answer += chunk
    except OSError as err:
        return f"it did not answer as a gRPC server ({err})"
    if len(answer) < 9 or answer[3] != 4:
        return f"it did not answer as a gRPC server (it sent {answer[:16]!r})"
    return None


def _connect_error(host_port: tuple[str, int], timeout_s: float = 2.0) -> OSError | None:
    """Why a TCP connection to ``host_port`` failed; None if something listens there."""
    try:
        socket.create_connection(host_port, timeout=timeout_s).close()
    except OSError as err:
        return err
    return None
