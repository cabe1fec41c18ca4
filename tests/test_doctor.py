"""``sensaug doctor``: each check against a fake /sys tree and fake rlimits
(the machine's own are whatever CI has), the SDO read against the virtual
CiA 402 drive on the loopback bus, and the command on this machine, which
has no CAN interface (the QEMU run of scripts/test-socketcan.sh runs it with
vcan0 up)."""

from __future__ import annotations

import resource
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sensaug import doctor, presets, rig
from sensaug.doctor import Host
from sensaug_bridge.udp_bus import free_port


def fake_sys(tmp: Path, interfaces: dict[str, dict[str, str]], isolated: str = "", governor: str | None = None,
             clocksource: str = "tsc", realtime: bool = False) -> Path:
    root = tmp / "sys"
    for name, files in interfaces.items():
        d = root / "class" / "net" / name
        d.mkdir(parents=True)
        for f, v in files.items():
            (d / f).write_text(v + "\n")
    cpu = root / "devices" / "system" / "cpu"
    cpu.mkdir(parents=True)
    (cpu / "isolated").write_text(isolated + "\n")
    if governor:
        (cpu / "cpu0" / "cpufreq").mkdir(parents=True)
        (cpu / "cpu0" / "cpufreq" / "scaling_governor").write_text(governor + "\n")
    cs = root / "devices" / "system" / "clocksource" / "clocksource0"
    cs.mkdir(parents=True)
    (cs / "current_clocksource").write_text(clocksource + "\n")
    if realtime:
        (root / "kernel").mkdir(parents=True)
        (root / "kernel" / "realtime").write_text("1\n")
    return root


def host(root: Path, ip: dict | None = None, rtprio: int = 0, memlock: int = 65536, euid: int = 1000,
         version: str = "#1 SMP PREEMPT_DYNAMIC") -> Host:
    limits = {resource.RLIMIT_RTPRIO: (rtprio, rtprio), resource.RLIMIT_MEMLOCK: (memlock, memlock)}
    return Host(sys=root, ip_details=lambda name: ip, getrlimit=lambda r: limits[r], euid=euid, kernel_version=version)


def by_name(checks):
    return {c.name: c for c in checks}


def test_a_missing_interface_fails_naming_the_fix(tmp_path):
    root = fake_sys(tmp_path, {"lo": {"type": "772"}, "can1": {"type": "280", "flags": "0x1"}})
    [c] = doctor.check_can("socketcan:can0", host(root))
    assert c.status == "fail" and "no interface can0" in c.found and "can1" in c.found
    assert "ip link add dev can0 type vcan" in c.fix


def test_a_vcan_that_is_up_passes_and_a_short_tx_queue_is_a_warning(tmp_path):
    root = fake_sys(tmp_path, {"vcan0": {"type": "280", "flags": "0x41", "tx_queue_len": "10"}})
    checks = by_name(doctor.check_can("socketcan:vcan0", host(root, {"linkinfo": {"info_kind": "vcan"}})))
    assert checks["CAN interface"].status == "ok" and "up" in checks["CAN interface"].found
    assert checks["CAN bitrate"].status == "skip"
    assert checks["CAN txqueuelen"].status == "warn" and "txqueuelen 1000" in checks["CAN txqueuelen"].fix


def test_an_adapter_that_is_down_at_another_bitrate_fails_both(tmp_path):
    root = fake_sys(tmp_path, {"can0": {"type": "280", "flags": "0x0", "tx_queue_len": "1000"}})
    ip = {"linkinfo": {"info_kind": "can", "info_data": {"bittiming": {"bitrate": 500000}}}}
    checks = by_name(doctor.check_can("socketcan:can0", host(root, ip)))
    assert checks["CAN interface"].status == "fail"
    assert "ip link set can0 up type can bitrate 1000000" in checks["CAN interface"].fix
    assert checks["CAN bitrate"].status == "fail" and "500000" in checks["CAN bitrate"].found
    assert checks["CAN txqueuelen"].status == "ok"
    ip["linkinfo"]["info_data"]["bittiming"]["bitrate"] = 1000000
    assert by_name(doctor.check_can("socketcan:can0", host(root, ip)))["CAN bitrate"].status == "ok"


def test_the_loopback_bus_needs_no_interface(tmp_path):
    [c] = doctor.check_can("udp:47100", host(fake_sys(tmp_path, {})))
    assert c.status == "ok"


def test_realtime_permissions_from_the_rlimits_or_root(tmp_path):
    root = fake_sys(tmp_path, {})
    user = by_name(doctor.check_realtime(host(root, rtprio=0, memlock=65536), 80, True))
    assert user["SCHED_FIFO"].status == "fail" and "rtprio 80" in user["SCHED_FIFO"].fix
    assert user["mlockall"].status == "fail" and "memlock unlimited" in user["mlockall"].fix
    assert user["PREEMPT_RT kernel"].status == "warn"
    granted = by_name(doctor.check_realtime(
        host(root, rtprio=99, memlock=resource.RLIM_INFINITY, version="#1 SMP PREEMPT_RT"), 80, True))
    assert [granted[n].status for n in ("SCHED_FIFO", "mlockall", "PREEMPT_RT kernel")] == ["ok", "ok", "ok"]
    as_root = by_name(doctor.check_realtime(host(fake_sys(tmp_path / "rt", {}, realtime=True), euid=0), 80, True))
    assert [as_root[n].status for n in ("SCHED_FIFO", "mlockall", "PREEMPT_RT kernel")] == ["ok", "ok", "ok"]


def test_isolated_cpus_governor_and_clock_source(tmp_path):
    good = by_name(doctor.check_cpus(host(fake_sys(tmp_path / "a", {}, "2-3", "performance")), 3))
    assert [good[n].status for n in ("CPU isolation", "CPU governor", "clock source")] == ["ok", "ok", "ok"]
    bad = by_name(doctor.check_cpus(host(fake_sys(tmp_path / "b", {}, "1", "powersave", "hpet")), 3))
    assert [bad[n].status for n in ("CPU isolation", "CPU governor", "clock source")] == ["warn", "warn", "warn"]
    assert "isolcpus=3" in bad["CPU isolation"].fix and "performance" in bad["CPU governor"].fix
    vm = by_name(doctor.check_cpus(host(fake_sys(tmp_path / "c", {})), None))
    assert vm["CPU governor"].status == "skip"


def test_the_sdo_read_finds_the_virtual_cia402_drive_and_nothing_where_none_is():
    port = free_port()
    drive = rig.start_drive(port, duration_s=30, drive="cia402")
    try:
        time.sleep(1.0)
        c = doctor.check_drive(f"udp:{port}", "cia402", 1, timeout_s=5.0)
        assert c.status == "ok" and "profile 402" in c.found, c
        assert doctor.check_drive(f"udp:{port}", "cia402", 2, timeout_s=0.5).status == "fail"
    finally:
        rig.stop_process(drive)
    nobody = doctor.check_drive(f"udp:{free_port()}", "cia402", 1, timeout_s=0.3)
    assert nobody.status == "fail" and "terminated" in nobody.fix


def test_the_command_on_this_machine_without_can(tmp_path):
    """The default (the virtual bus) passes; socketcan:can0 fails (no CAN
    here: exit 1, saying so and how to bring an interface up)."""
    ok = subprocess.run([sys.executable, "-m", "sensaug", "doctor"], capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert "[ok  ] CAN link: udp:" in ok.stdout and "sensaug-rt" in ok.stdout
    if Path("/sys/class/net/can0").exists():
        pytest.skip("this machine has a can0: the no-CAN case does not apply")
    cfg = presets.hi5_rig()
    cfg.rig.can = "socketcan:can0"
    cfg.to_toml(tmp_path / "can0.toml")
    no_can = subprocess.run([sys.executable, "-m", "sensaug", "doctor", str(tmp_path / "can0.toml")],
                            capture_output=True, text=True, timeout=60)
    assert no_can.returncode == 1, no_can.stdout
    assert "[FAIL] CAN interface: no interface can0" in no_can.stdout and "fix:" in no_can.stdout
