"""``sensaug doctor [CONFIG]``: is this host ready for a rig run?

Each check prints one line, ``ok``, ``warn`` or ``FAIL``, what it found and,
when not ok, the fix (docs/hardware.md has the reasons). What is checked:

* the CAN link of ``rig.can`` (or ``--can``): a ``socketcan:IF`` interface
  exists, is up, runs at the expected bitrate (``--bitrate``, default
  1 Mbit/s; a vcan has none) and has a transmit queue long enough not to
  return ENOBUFS on a burst (txqueuelen >= 1000; python-can #310, #2004);
  the loopback ``udp:PORT`` bus needs none of that;
* permission for SCHED_FIFO at ``rig.realtime.fifo_priority`` and for
  ``mlockall`` (RLIMIT_RTPRIO, RLIMIT_MEMLOCK, or root);
* the kernel: PREEMPT_RT or not; isolated CPUs (``isolcpus``) and whether
  ``rig.realtime.cpu`` is one; the CPU frequency governor; the clock source;
* the ``sensaug-rt`` binary;
* with ``--sdo`` (opt-in: it sends a frame), the drive answering an SDO read
  of 0x1000 (device type) at ``rig.node_id`` (CiA 402; the Hi5 drive has no
  SDO server: its heartbeat is listened for instead).

Exit code: 0 when nothing failed (warnings allowed), 1 when a check failed,
2 for a bad configuration. /sys, /proc and ``ip`` are reached through
:class:`Host`, which the tests replace with a fake tree.
"""

from __future__ import annotations

import json
import os
import platform
import resource
import struct
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

#: Transmit queue length below which a burst of frames gets ENOBUFS.
MIN_TXQUEUELEN = 1000
#: The bitrate both drive profiles use (docs/hardware.md).
DEFAULT_BITRATE = 1_000_000
IFF_UP = 0x1


@dataclass
class Check:
    """One item: its name, status ("ok", "warn", "fail", "skip"), what was
    found, and the fix when not ok."""

    name: str
    status: str
    found: str
    fix: str = ""

    def line(self) -> str:
        mark = {"ok": "ok  ", "warn": "warn", "fail": "FAIL", "skip": "skip"}[self.status]
        out = f"[{mark}] {self.name}: {self.found}"
        return out + (f"\n       fix: {self.fix}" if self.fix and self.status in ("warn", "fail") else "")


@dataclass
class Host:
    """Where the checks read the machine: ``sys`` and ``proc`` roots, the
    ``ip`` command's JSON for an interface, the rlimits, the user id."""

    sys: Path = Path("/sys")
    proc: Path = Path("/proc")
    ip_details: Callable[[str], Optional[dict]] = field(default=lambda name: _ip_details(name))
    getrlimit: Callable[[int], tuple[int, int]] = resource.getrlimit
    euid: int = field(default_factory=os.geteuid)
    kernel_version: str = field(default_factory=platform.version)

    def read(self, path: Path) -> Optional[str]:
        try:
            return path.read_text().strip()
        except OSError:
            return None


def _ip_details(name: str) -> Optional[dict]:
    """``ip -details -json link show NAME``'s entry, or None."""
    try:
        out = subprocess.run(["ip", "-details", "-json", "link", "show", name], capture_output=True, text=True,
                             timeout=5)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if out.returncode != 0:
        return None
    try:
        entries = json.loads(out.stdout)
    except json.JSONDecodeError:
        return None
    return entries[0] if entries else None


def check_can(url: str, host: Host, bitrate: int = DEFAULT_BITRATE) -> list[Check]:
    """The interface of ``url``: exists, up, bitrate, txqueuelen."""
    if url.startswith("udp:"):
        return [Check("CAN link", "ok", f"{url}: the loopback virtual bus (no CAN interface needed)")]
    if not url.startswith("socketcan:"):
        return [Check("CAN link", "fail", f"{url}: neither udp:PORT nor socketcan:IF",
                      "set rig.can (or --can) to socketcan:can0 for an adapter, udp:47100 for the virtual rig")]
    name = url.split(":", 1)[1]
    net = host.sys / "class" / "net" / name
    if not net.exists():
        present = sorted(p.name for p in (host.sys / "class" / "net").glob("*")) if (host.sys / "class" / "net").exists() else []
        cans = [n for n in present if host.read(host.sys / "class" / "net" / n / "type") == "280"]
        return [Check("CAN interface", "fail",
                      f"no interface {name} (CAN interfaces on this host: {', '.join(cans) or 'none'})",
                      f"plug in the adapter and load its driver (docs/hardware.md, 'Adapters'); for a test without "
                      f"hardware: sudo modprobe vcan && sudo ip link add dev {name} type vcan")]
    checks = []
    kind = host.read(net / "type")
    if kind != "280":  # ARPHRD_CAN
        checks.append(Check("CAN interface", "fail", f"{name} is not a CAN interface (type {kind})",
                            "set rig.can to the adapter's interface (ip -details link show)"))
        return checks
    flags = host.read(net / "flags")
    up = flags is not None and int(flags, 16) & IFF_UP
    details = host.ip_details(name) or {}
    info = details.get("linkinfo", {})
    is_vcan = info.get("info_kind") == "vcan"
    checks.append(Check("CAN interface", "ok" if up else "fail",
                        f"{name} ({'virtual, vcan' if is_vcan else info.get('info_kind', 'can')}) is {'up' if up else 'down'}",
                        f"sudo ip link set {name} up type can bitrate {bitrate}" if not is_vcan
                        else f"sudo ip link set {name} up"))
    if is_vcan:
        checks.append(Check("CAN bitrate", "skip", f"{name} is a vcan: no bitrate"))
    else:
        have = info.get("info_data", {}).get("bittiming", {}).get("bitrate")
        checks.append(Check("CAN bitrate", "ok" if have == bitrate else "fail",
                            f"{name} at {have} bit/s, expected {bitrate}" if have else f"{name}: bitrate not set",
                            f"sudo ip link set {name} down; sudo ip link set {name} up type can bitrate {bitrate}"))
    txq = host.read(net / "tx_queue_len")
    n = int(txq) if txq and txq.isdigit() else 0
    checks.append(Check("CAN txqueuelen", "ok" if n >= MIN_TXQUEUELEN else "warn",
                        f"{name} txqueuelen {n} (>= {MIN_TXQUEUELEN} keeps a burst from getting ENOBUFS)",
                        f"sudo ip link set {name} txqueuelen {MIN_TXQUEUELEN}"))
    return checks


def check_realtime(host: Host, fifo_priority: Optional[int], mlockall: bool) -> list[Check]:
    """SCHED_FIFO and mlockall permissions, PREEMPT_RT."""
    checks = []
    root = host.euid == 0
    if fifo_priority is None:
        checks.append(Check("SCHED_FIFO", "skip", "rig.realtime.fifo_priority not set: the loop runs SCHED_OTHER"))
    else:
        soft, _ = host.getrlimit(resource.RLIMIT_RTPRIO)
        allowed = root or soft == resource.RLIM_INFINITY or soft >= fifo_priority
        checks.append(Check("SCHED_FIFO", "ok" if allowed else "fail",
                            f"priority {fifo_priority}: {'root' if root else f'RLIMIT_RTPRIO {soft}'}",
                            f"add '@realtime - rtprio {fifo_priority}' to /etc/security/limits.d/99-realtime.conf "
                            f"and put the user in group realtime (log in again)"))
    if not mlockall:
        checks.append(Check("mlockall", "skip", "rig.realtime.mlockall = false"))
    else:
        soft, _ = host.getrlimit(resource.RLIMIT_MEMLOCK)
        allowed = root or soft == resource.RLIM_INFINITY
        checks.append(Check("mlockall", "ok" if allowed else "fail",
                            "root" if root else f"RLIMIT_MEMLOCK {soft} bytes",
                            "add '@realtime - memlock unlimited' to /etc/security/limits.d/99-realtime.conf"))
    rt = host.read(host.sys / "kernel" / "realtime") == "1" or "PREEMPT_RT" in host.kernel_version
    checks.append(Check("PREEMPT_RT kernel", "ok" if rt else "warn",
                        host.kernel_version if rt else f"not a real-time kernel ({host.kernel_version})",
                        "install a PREEMPT_RT kernel (Debian: linux-image-rt-amd64) and boot it"))
    return checks


def check_cpus(host: Host, cpu: Optional[int]) -> list[Check]:
    """Isolated CPUs, the loop's CPU among them, the governor, the clock source."""
    checks = []
    isolated = host.read(host.sys / "devices" / "system" / "cpu" / "isolated") or ""
    cpus = _cpu_list(isolated)
    if cpu is None:
        checks.append(Check("CPU isolation", "ok" if cpus else "warn",
                            f"isolated CPUs: {isolated or 'none'}; rig.realtime.cpu not set",
                            "boot with isolcpus=3 nohz_full=3 rcu_nocbs=3 and set rig.realtime.cpu = 3"))
    else:
        checks.append(Check("CPU isolation", "ok" if cpu in cpus else "warn",
                            f"rig.realtime.cpu = {cpu}; isolated CPUs: {isolated or 'none'}",
                            f"boot with isolcpus={cpu} nohz_full={cpu} rcu_nocbs={cpu}"))
    governors = {
        host.read(p) for p in sorted((host.sys / "devices" / "system" / "cpu").glob("cpu[0-9]*/cpufreq/scaling_governor"))
    } - {None}
    if not governors:
        checks.append(Check("CPU governor", "skip", "no cpufreq (a virtual machine, or fixed frequency)"))
    else:
        ok = governors == {"performance"}
        checks.append(Check("CPU governor", "ok" if ok else "warn", ", ".join(sorted(governors)),
                            "sudo cpupower frequency-set -g performance"))
    source = host.read(host.sys / "devices" / "system" / "clocksource" / "clocksource0" / "current_clocksource")
    checks.append(Check("clock source", "ok" if source == "tsc" else "warn", source or "unknown",
                        "a slow clock source (hpet, acpi_pm) adds microseconds to every clock read: "
                        "check the BIOS and dmesg for why tsc was rejected"))
    return checks


def _cpu_list(text: str) -> set[int]:
    """'1,3-5' -> {1, 3, 4, 5}."""
    out: set[int] = set()
    for part in filter(None, text.split(",")):
        lo, _, hi = part.partition("-")
        out.update(range(int(lo), int(hi or lo) + 1))
    return out


def check_binary() -> Check:
    from sensaug import _resources

    try:
        path = _resources.rt_binary()
    except FileNotFoundError as e:
        return Check("sensaug-rt", "fail", str(e), "bash scripts/setup.sh (builds target/release/sensaug-rt)")
    return Check("sensaug-rt", "ok", str(path))


def check_drive(url: str, drive: str, node: int, timeout_s: float = 1.0) -> Check:
    """The drive at ``node`` answers: CiA 402, an SDO upload of 0x1000
    (device type: profile 402 expected); Hi5, its heartbeat. Sends one
    frame (CiA 402) or none (Hi5)."""
    import can

    if url.startswith("udp:"):
        bus = can.Bus(interface="sensaug_udp", channel=int(url.split(":", 1)[1]))
    else:
        bus = can.Bus(interface="socketcan", channel=url.split(":", 1)[1])
    try:
        if drive == "cia402":
            bus.send(can.Message(arbitration_id=0x600 + node, data=struct.pack("<BHB4x", 0x40, 0x1000, 0),
                                 is_extended_id=False))
            want = 0x580 + node
        else:
            want = None
        end = time.monotonic() + timeout_s
        while (left := end - time.monotonic()) > 0:
            msg = bus.recv(left)
            if msg is None:
                break
            if drive == "cia402" and msg.arbitration_id == want and len(msg.data) == 8:
                if msg.data[0] == 0x80:
                    code = struct.unpack_from("<I", msg.data, 4)[0]
                    return Check("drive", "fail", f"node {node} aborted the SDO read of 0x1000 ({code:#010x})",
                                 "check rig.node_id against the drive's node-ID")
                device = struct.unpack_from("<I", msg.data, 4)[0]
                profile = device & 0xFFFF
                return Check("drive", "ok" if profile == 402 else "fail",
                             f"node {node} answers: device type {device:#010x} (profile {profile})",
                             "not a CiA 402 drive: check rig.drive and rig.node_id")
            if drive != "cia402" and msg.arbitration_id == 0x700 + node:
                return Check("drive", "ok", f"node {node}'s heartbeat heard")
    finally:
        bus.shutdown()
    return Check("drive", "fail", f"no answer from node {node} within {timeout_s:g} s",
                 "is the drive powered, on this bus, at rig.node_id, and the bus terminated (120 ohm at each end)?")


def run_checks(url: str, rig, host: Host, *, bitrate: int = DEFAULT_BITRATE, sdo: bool = False) -> list[Check]:
    rt = rig.realtime
    checks = [*check_can(url, host, bitrate), *check_realtime(host, rt.fifo_priority, rt.mlockall),
              *check_cpus(host, rt.cpu), check_binary()]
    if sdo:
        can_ok = all(c.status != "fail" for c in checks if c.name.startswith("CAN"))
        checks.append(check_drive(url, rig.drive, rig.node_id) if can_ok
                      else Check("drive", "skip", "the CAN link failed its checks"))
    else:
        checks.append(Check("drive", "skip", "not asked (--sdo sends a frame to the drive)"))
    return checks


def main(config: Optional[Path], can_url: Optional[str], bitrate: int, sdo: bool, host: Optional[Host] = None) -> int:
    from sensaug import presets
    from sensaug.config import ConfigError, ScenarioConfig

    try:
        cfg = ScenarioConfig.from_toml(config) if config else presets.hi5_rig()
    except (ConfigError, OSError, ValueError) as e:
        print(f"sensaug doctor: {e}")
        return 2
    url = can_url or cfg.rig.can
    print(f"sensaug doctor: {config or 'the hi5-rig preset'}, CAN {url}, drive {cfg.rig.drive} node {cfg.rig.node_id}")
    checks = run_checks(url, cfg.rig, host or Host(), bitrate=bitrate, sdo=sdo)
    for c in checks:
        print(c.line())
    failed = [c.name for c in checks if c.status == "fail"]
    warned = [c.name for c in checks if c.status == "warn"]
    print(f"{len(failed)} failed, {len(warned)} warnings" + (f": {', '.join(failed)} must be fixed" if failed else ""))
    return 1 if failed else 0
