"""Run the real compiled bridge firmware under simavr with a plant model of the rig.

``Emulator(board, rig)`` builds what is missing (``make -C firmware``), starts the C
harness ``firmware/build/emulator/labrig-emu`` and exposes its pseudo-terminal as
``emu.pty``, which :class:`labrig.bridge.serial.SerialBridge` opens like a USB port::

    with Emulator("uno", rig) as emu:
        with SerialBridge(emu.pty, rig) as bridge:
            ...
"""
from __future__ import annotations

import fcntl
import math
import os
import re
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from labrig.bridge import hbridge
from labrig.io.config import RigConfig
from labrig.core.errors import RigError, UserError

FIRMWARE_DIR = Path(os.environ.get("LABRIG_FIRMWARE_DIR",
                                   Path(__file__).resolve().parents[2] / "firmware"))
APT_PACKAGES = "gcc-avr avr-libc arduino-core-avr simavr libsimavr-dev libsimavrparts1"
BOARDS = ("uno", "nano", "mega")

def missing_build_tools() -> list[str]:
    """What is missing to build the firmware for the boards (empty when all is there)."""
    missing = [t for t in ("make", "avr-gcc", "avr-objcopy", "avr-size") if not shutil.which(t)]
    if not Path("/usr/share/arduino/hardware/arduino/avr/cores/arduino/Arduino.h").exists():
        missing.append("arduino-core-avr")
    if not Path("/usr/lib/avr/include/avr/io.h").exists():
        missing.append("avr-libc")
    return missing


def missing_tools() -> list[str]:
    """What is missing to build and run the emulator (empty when all is there)."""
    missing = missing_build_tools() + ([] if shutil.which("gcc") else ["gcc"])
    if not Path("/usr/include/simavr/sim_avr.h").exists():
        missing.append("libsimavr-dev")
    return missing


def build_firmware(board: str, rig: RigConfig | None = None, *extra: str,
                   watchdog: bool = True, test_hooks: bool = False) -> Path:
    """Build (incrementally) the firmware for ``board`` (``make -C firmware``), the rig's
    ``[bridge]`` build, with ``extra`` targets; return the folder of its ``labrig_bridge``
    ELF and hex.

    Raises
    ------
    RigError
        The tail of the compiler output when the build fails.
    """
    options = ((hbridge.make_options(rig) if rig is not None else [])
               + ([] if watchdog else ["HW_WATCHDOG=0"]) + (["TEST_HOOKS=1"] if test_hooks else []))
    r = firmware_make(board, *extra, *options)
    if r.returncode != 0:
        tail = "\n".join((r.stdout + r.stderr).strip().splitlines()[-15:])
        raise RigError(f"firmware build failed (make -C {FIRMWARE_DIR} {board} "
                       f"{' '.join([*extra, *options])}):\n{tail}")
    # the Makefile's folders: the rig's build, then nowdt/ and testhooks/ below it
    folder = FIRMWARE_DIR / "build" / (hbridge.build_folder(rig) if rig is not None else "")
    folder = folder / ("" if watchdog else "nowdt") / ("testhooks" if test_hooks else "")
    return folder / board


def firmware_make(*targets: str, timeout: float | None = None) -> subprocess.CompletedProcess:
    """``make -C firmware TARGETS``, one at a time across processes: two builds in the one
    build folder remove each other's objects (one's ``rm -f core.a`` lands between the
    other's archive and its link), so each holds an exclusive lock on the folder's lock
    file for the whole build."""
    lock = FIRMWARE_DIR / "build" / ".make.lock"
    lock.parent.mkdir(parents=True, exist_ok=True)
    with open(lock, "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)   # released when the file closes, whatever happens
        return subprocess.run(["make", "-C", str(FIRMWARE_DIR), "--no-print-directory",
                               *targets], capture_output=True, text=True, timeout=timeout)


def build(board: str = "uno", rig: RigConfig | None = None,
          test_hooks: bool = False) -> tuple[Path, Path]:
    """Build (incrementally) the firmware for ``board`` and the harness.

    The rig's ``[bridge] firmware`` picks the hardware layer (the MS150 bridge by default;
    ``hbridge`` with its PWM bits, drive, off phase, decoding and current sense).

    Returns
    -------
    (elf, harness) : tuple of Path

    Raises
    ------
    RigError
        With the exact apt packages to install when the toolchain is missing, or the tail of
        the compiler output when the build fails.
    """
    if board not in BOARDS:
        raise UserError(f"unknown board {board!r}: uno, nano or mega")
    missing = missing_tools()
    if missing:
        raise RigError(f"cannot build the emulator: {', '.join(missing)} missing; install with: "
                       f"apt-get install -y --no-install-recommends {APT_PACKAGES}")
    folder = build_firmware(board, rig, "emulator", test_hooks=test_hooks)
    return folder / "labrig_bridge.elf", FIRMWARE_DIR / "build" / "emulator" / "labrig-emu"


def plant_args(rig: RigConfig) -> list[str]:
    """Harness command-line options for the plant of ``rig``.

    The rig's hidden Coulomb friction (``[effects.coulomb_friction]``) is the one effect the
    harness models; without it the plant has none. The MS150's analog loop gets the gains the
    rig file says are patched (``[bridge] loop_kp, loop_kv``), as a patch panel would: the
    plan's gains never reach it.
    """
    p, amp, sen, noise = rig.plant, rig.amplifier, rig.sensors, rig.noise
    tc_v = rig.effects.get("coulomb_friction", {}).get("tc_v", 0.0)
    v = {"R": p.R, "L": p.L, "J": p.J, "B": p.B, "K": p.K, "Ka": amp.gain,
         "Vmax": amp.output_limit_v, "N": rig.gear_ratio, "Kt": sen.tacho_v_per_rad_s,
         "Kpot": sen.pos_v_per_rad, "pos-offset": sen.pos_offset_v, "noise-tacho": noise.tacho_v,
         "noise-pos": noise.pos_v,
         # the catalogue gives friction in bridge volts, the harness a motor torque
         "Tc": tc_v * amp.gain * p.K / p.R, "seed": noise.seed}
    if rig.bridge.firmware == "hbridge":
        return _hbridge_args(rig, v)
    if rig.bridge.loop_kp is not None:   # the patch panel's knobs, as the rig file says
        v.update(kp=float(rig.bridge.loop_kp), kv=float(rig.bridge.loop_kv))
    return [a for k, val in v.items() for a in (f"--{k}", str(int(val)) if k == "seed" else repr(val))]


def _hbridge_args(rig: RigConfig, v: dict) -> list[str]:
    """The harness options of an H-bridge rig: its motor, supply, bridge and encoder, and
    the hidden effects the harness models physically -- the bridge's dead zone
    (``deadband``, ``asymmetric_deadband``: a turn-on delay that swallows that share of every
    pulse), Coulomb friction and stiction (torques at the motor), the gear's play
    (``backlash``, with the encoder on the output shaft). Other catalogue effects are not
    in the emulated plant."""
    p, fx = rig.plant, rig.effects
    to_torque = p.K / p.R   # a friction in bridge volts, as a torque (the bridge's gain is 1)
    b = rig.bridge
    dead_f = fx.get("deadband", {}).get("d_v", 0.0) or fx.get("asymmetric_deadband", {}).get("dpos_v", 0.0)
    dead_r = fx.get("deadband", {}).get("d_v", 0.0) or fx.get("asymmetric_deadband", {}).get("dneg_v", 0.0)
    tc_v = fx.get("coulomb_friction", {}).get("tc_v", 0.0) or fx.get("stiction", {}).get("tc_v", 0.0)
    ts_v = tc_v * (1 + fx.get("stiction", {}).get("excess", 0.0)) if "stiction" in fx else 0.0
    per_turn = rig.sensors.encoder_counts_per_unit * 2 * math.pi / b.decoding
    # the encoder on the output shaft where the gear's play is to be seen, or where the
    # rig file's index comes once an output turn
    on_output = "backlash" in fx or (
        b.index_counts > 0 and abs(b.index_counts - per_turn * b.decoding) <= 0.002 * b.index_counts)
    args = {"rig": "hbridge", "R": p.R, "L": p.L, "J": p.J, "B": p.B, "K": p.K, "N": v["N"],
            "supply": float(b.dac_range_v[1]), "dead-fwd": dead_f, "dead-rev": dead_r,
            "Tc": tc_v * to_torque, "Ts": ts_v * to_torque,
            "backlash": 2 * fx.get("backlash", {}).get("a_rad", 0.0),
            "lines": per_turn if on_output else per_turn / rig.gear_ratio, "seed": v["seed"]}
    out = [a for k, val in args.items()
           for a in (f"--{k}", val if isinstance(val, str) else
                     str(int(val)) if k == "seed" else repr(float(val)))]
    if on_output:
        out.append("--encoder-on-output")
    if b.index_counts:   # the index the rig file wires, once a turn of the encoder's shaft
        out.append("--index")
    if b.current_sense:   # the sense amplifier the rig file describes, on A0
        out += ["--current-v-per-a", repr(float(rig.sensors.current_v_per_a)),
                "--current-zero", repr(float(rig.sensors.current_zero_v))]
    if b.drive_mode == "in1_in2":
        out.append("--in1-in2")
    elif b.off_phase == "brake":
        out.append("--brake")   # a PWM + DIR driver that brakes between pulses
    return out


class Emulator:
    """The firmware for ``board`` running under simavr, its UART on ``self.pty``.

    Parameters
    ----------
    board : {"uno", "nano", "mega"}
    rig : labrig.io.config.RigConfig, optional
        Rig whose plant the harness simulates; ``RigConfig()`` (the default rig's values,
        without its hidden friction) when not given.
    speed : float
        1.0 paces the simulation to real time (host timeouts and the watchdog as on the
        bench); 0 runs as fast as the machine allows.
    dac_log : str or Path, optional
        File where the harness logs every change of the DAC output word
        (``<simulated seconds> <word>`` per line); on an H-bridge rig, ``T cycle`` when the
        sample clock starts, ``E cycle edge`` at every encoder edge and ``D cycle duty``
        at every change of the commanded signed duty (timer counts).
    loop : {"open", "closed"}, optional
        Force the plant's loop; by default the patch panel is re-patched to each CONFIGURE's
        loop mode, as the student does between runs (its gains stay the rig file's).
    extra_args : tuple of str
        More harness options (``--estop-at S``, ``--index``, ...).
    test_hooks : bool
        Run the test build (``make TEST_HOOKS=1``), in which message 0x7E stops the
        firmware's main loop as a hang would (the hardware watchdog's test); never flashed.
    bootloader : str or Path, optional
        A board as it comes from the box: this bootloader (Intel hex) in its section, run
        from reset, the application flash erased; avrdude uploads through it over the pty
        (``labrig flash``), and the bootloader then starts what was written.
    eeprom : str or Path, optional
        The chip's EEPROM (the board's id) kept in this file across runs: read at start
        (a missing file: erased), written back when the emulator stops.

    Notes
    -----
    The harness ends with the process that started it (Linux ``PR_SET_PDEATHSIG``; strictly,
    with the thread that called :meth:`start`, so start it from a thread that lives as long
    as the emulator is needed, normally the main thread). It runs in its own session, so a
    Ctrl-C meant for the host never reaches it; :meth:`stop` ends it by its PID.
    """

    #: the largest lag behind real time of every emulator stopped in this process, in
    #: seconds (:meth:`behind_s`; the tests report it beside a timing failure)
    lags: list = []
    #: the emulators of this process that are running
    running: set = set()

    def __init__(self, board: str = "uno", rig: RigConfig | None = None, *, speed: float = 1.0,
                 dac_log=None, loop: str | None = None, extra_args: tuple = (),
                 test_hooks: bool = False, bootloader=None, eeprom=None):
        self.board, self.speed = board, speed
        self.bootloader = str(bootloader) if bootloader else None
        self.eeprom = str(eeprom) if eeprom else None
        self.rig = rig if rig is not None else RigConfig()
        self.dac_log = str(dac_log) if dac_log else None
        self.loop, self.extra_args = loop, tuple(extra_args)
        self.test_hooks = test_hooks   # the test build (firmware/Makefile TEST_HOOKS=1)
        self.proc: subprocess.Popen | None = None
        self.pty: str | None = None
        self._log = None

    def command(self) -> list[str]:
        elf, harness = build(self.board, self.rig, self.test_hooks)
        # --parent-pid: the harness exits when this process dies (PR_SET_PDEATHSIG), even by
        # SIGKILL, so no emulator outlives its owner and nothing needs killing by name
        image = ["--bootloader", self.bootloader] if self.bootloader else ["--fw", str(elf)]
        cmd = [str(harness), *image, "--board", self.board, "--speed", repr(self.speed),
               "--parent-pid", str(os.getpid())]
        cmd += plant_args(self.rig)
        if self.dac_log:   # an H-bridge board's log: sample clock, encoder edges, duty
            cmd += ["--enc-log" if self.rig.bridge.firmware == "hbridge" else "--dac-log",
                    self.dac_log]
        if self.loop:
            cmd += ["--loop", self.loop]
        if self.eeprom:
            cmd += ["--eeprom", self.eeprom]
        return cmd + list(self.extra_args)

    def start(self, timeout: float = 10.0) -> str:
        """Start the harness; return the pty path (its first line of stdout)."""
        cmd = self.command()
        # stderr to a file: simavr chats there and an unread pipe would stall it. A file
        # without a name: it goes with the last process that holds it, however that ends
        self._log = tempfile.TemporaryFile(prefix="labrig-emu-", suffix=".log")
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self._log, text=True,
                                     start_new_session=True)
        deadline = time.monotonic() + timeout
        line = self.proc.stdout.readline().strip()
        if not line.startswith("/dev/") or time.monotonic() > deadline:
            self.stop()
            raise RigError(f"emulator did not start: {self.log_text()[-500:]}")
        self.pty = line
        Emulator.running.add(self)
        return line

    def log_text(self) -> str:
        """What the harness wrote to stderr so far."""
        try:   # (pread: the harness writes through the same offset, which must not move)
            fd = self._log.fileno()
            return os.pread(fd, os.fstat(fd).st_size, 0).decode(errors="replace")
        except (AttributeError, OSError, ValueError):   # no log yet, or closed
            return ""

    def behind_s(self) -> float:
        """How far the simulation has fallen behind real time at most, in seconds (0 when
        it kept up, or runs free): a machine too busy for a real-time board."""
        said = re.findall(r"behind real time by (\d+) ms", self.log_text())
        return max((int(v) for v in said), default=0) / 1e3

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self) -> None:
        """Stop the harness (SIGTERM, then SIGKILL after 3 s); never raises."""
        if self._log is not None:
            Emulator.lags.append(self.behind_s())
        Emulator.running.discard(self)
        p, self.proc = self.proc, None
        if p is not None:
            try:
                if p.poll() is None:
                    p.send_signal(signal.SIGTERM)
                    try:
                        p.wait(3)
                    except subprocess.TimeoutExpired:
                        p.kill()
                        p.wait(3)
            except Exception:
                pass
            if p.stdout:
                p.stdout.close()
        if self._log is not None:
            self._log.close()
            self._log = None

    def __enter__(self) -> "Emulator":
        self.start()
        return self

    def __exit__(self, *exc) -> bool:
        self.stop()
        return False
