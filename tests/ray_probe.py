"""What Ray left running and where it listens, read from /proc (tests of the --ray paths).

A test takes ``ray_processes()`` before and after its run: the processes a local Ray instance
started (gcs_server, raylet, workers renamed ``ray::...``, Ray's Python agents) must all be gone
once the run returns, and while it runs none of them may listen beyond loopback.
"""
from __future__ import annotations

import ipaddress
import os
import time
from pathlib import Path


def ray_processes() -> set[int]:
    """PIDs of the live processes that belong to some Ray instance on this machine."""
    pids = set()
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            cmd = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (proc / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z" and ("ray::" in cmd or "/site-packages/ray/" in cmd):
            pids.add(int(proc.name))
    return pids


def wait_gone(pids: set[int], timeout_s: float = 30.0) -> set[int]:
    """Those of ``pids`` still alive after up to ``timeout_s`` (Ray stops its processes asynchronously)."""
    deadline = time.monotonic() + timeout_s
    alive = set(pids)
    while alive and time.monotonic() < deadline:
        time.sleep(0.2)
        alive &= ray_processes()
    return alive


def listening_addresses(pids: set[int]) -> list[tuple[int, str]]:
    """(pid, local IP) of every TCP socket the processes listen on."""
    inodes: dict[str, int] = {}
    for pid in pids:
        try:
            for fd in Path(f"/proc/{pid}/fd").iterdir():
                target = os.readlink(fd)
                if target.startswith("socket:["):
                    inodes[target[8:-1]] = pid
        except OSError:
            continue
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            cols = line.split()
            if cols[3] == "0A" and cols[9] in inodes:  # 0A: LISTEN
                found.append((inodes[cols[9]], _ip(cols[1].split(":")[0])))
    return found


def _ip(hex_addr: str) -> str:
    """/proc/net/tcp{,6} address (little-endian 32-bit words) as text."""
    raw = bytes.fromhex(hex_addr)
    words = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
    ip = ipaddress.ip_address(words)
    return str(ip.ipv4_mapped or ip) if isinstance(ip, ipaddress.IPv6Address) else str(ip)


def is_loopback(ip: str) -> bool:
    return ipaddress.ip_address(ip).is_loopback
