"""Acquisition: a bridge to the rig (simulated, the board, the emulated board) and a
sweep played on it."""
from __future__ import annotations

from labrig.core.progress import Event, both
from labrig.verbs.data import runs_of


def sweep(output, plan=None, rig=None, *, port: str | None = None, seed: int | None = None,
          resume: bool = False, on_progress=None, progress=None):
    """Play a plan on the simulated rig (default) or the board at ``port`` and write one
    run per experiment to ``output`` (``labrig sweep``); returns the runs read back.

    Parameters
    ----------
    output : str or Path
        Folder for the runs; an existing run there is refused unless ``resume``.
    plan, rig : str or Path, optional
        Plan and rig files (TOML; a rig may be a ``.mystery`` file); default the lab's
        standard plan and the MS150 rig.
    port : str, optional
        Serial device of the bridge; without it the simulated rig plays the plan.
    seed : int, optional
        Noise seed of the simulated rig (default: the rig file's).
    on_progress : callable(n_samples), optional
        Called as samples arrive.
    progress : callable(Event), optional
        Hears each experiment start, its samples arrive and its run written (:func:`play`).

    Returns
    -------
    list of Run
        The runs written, read back.

    Raises
    ------
    UserError
        A plan or rig file that does not validate, or a run already in ``output``.
    RigError
        The board failed mid-run (the finished runs are kept, the output left at 0 V).
    Interrupted
        Ctrl-C: the finished runs are kept and the output left at 0 V.

    Examples
    --------
    >>> import labrig as lr
    >>> runs = lr.sweep("runs")  # doctest: +SKIP
    >>> [r.name for r in runs][:2]  # doctest: +SKIP
    ['cl_sq_0.50V', 'cl_sq_0.60V']
    """
    from labrig.verbs.data import load_plan, load_rig

    rig_cfg = load_rig(rig)
    experiments = load_plan(plan, rig_cfg)
    make, _, _ = open_bridge(rig_cfg, port=port, seed=seed)
    written = play(make(), experiments, rig_cfg, output, resume=resume,
                   on_progress=on_progress, progress=progress)
    return runs_of([str(p) for p in written]) if written else runs_of(output)


def open_bridge(rig, *, port: str | None = None, emulate: bool = False, seed: int | None = None,
                board_id: int | None = None, baud: int = 500000):
    """How to reach the rig: ``(make, name, close)``, where ``make()`` gives a fresh
    bridge for each sweep (the board at ``port``, the real firmware in simavr with
    ``emulate``, else the simulated rig with its noise ``seed``), ``name`` says which in
    words and ``close()`` ends what was started (the emulator). ``board_id`` binds the
    station to one board: another board on ``port`` is refused when it greets; ``baud`` is
    the serial speed of the board's firmware."""
    if port:   # held from now until close(): no other process takes the board between runs
        from labrig.bridge.serial import SerialBridge
        from labrig.bridge.transport import lease, release

        lease(port)
        return ((lambda: SerialBridge(port, rig, board_id=board_id, baudrate=baud)),
                f"board at {port}",
                (lambda: release(port)))
    if emulate:
        from labrig.bridge.serial import SerialBridge
        from labrig.bridge.transport import lease, release

        emu = emulator(rig)
        pty = emu.start()
        lease(pty)
        return ((lambda: SerialBridge(pty, rig)), f"emulated board ({pty})",
                lambda: (release(pty), emu.stop()))
    from labrig.bridge.sim import SimRig

    name = rig.name or "MS150"   # (a rig file's name may already say it is simulated)
    name = name if "simulated" in name.lower() else f"simulated {name}"
    return (lambda: SimRig(rig, seed=seed)), name, (lambda: None)


def live(bridge, on_block=None, **options):
    """``bridge`` with every block of samples handed to ``on_block`` as it arrives (the
    lab's live view, the command line's real-time pace): a
    :class:`~labrig.bridge.live.LiveBridge`."""
    from labrig.bridge.live import LiveBridge

    return LiveBridge(bridge, on_block, **options)


def play(bridge, plan, rig, output, *, resume: bool = False, on_start=None, on_progress=None,
         on_done=None, progress=None) -> list:
    """Play ``plan`` on ``bridge`` and write each run to ``output`` as it finishes (what
    :func:`sweep` does on a bridge of its own); the hooks see each experiment start,
    its samples arrive and its run written, and ``progress(event)`` hears all three
    (kinds ``experiment``, ``samples``, ``run``). Returns the paths written."""
    from labrig.bridge.sweep import sweep as _sweep

    if progress is not None:
        on_start = both(on_start, lambda e: progress(Event("sweep", "experiment", text=e.name,
                                                           data=e)))
        on_progress = both(on_progress, lambda n: progress(Event("sweep", "samples", n)))
        on_done = both(on_done, lambda e, r: progress(Event("sweep", "run", text=e.name,
                                                            data=r)))
    return _sweep(bridge, plan, rig, output, resume=resume, on_start=on_start,
                  on_progress=on_progress, on_done=on_done)


def emulator(rig, *, board: str | None = None, speed: float = 1.0, eeprom=None):
    """The real firmware for ``board`` (default: the rig file's ``bridge.board``, else the
    Uno) under simavr, fed by a plant model of ``rig``: an
    :class:`~labrig.bridge.emulate.Emulator` (``start()`` gives its pty, ``stop()`` ends it).
    ``eeprom``: a file keeping the chip's EEPROM (the board's id) across runs."""
    from labrig.bridge.emulate import Emulator
    from labrig.io.board_pins import board_for

    return Emulator(board=board_for(rig, board), rig=rig, speed=speed, eeprom=eeprom)


def wiring(rig, *, board: str | None = None):
    """How to wire ``rig``'s bridge to ``board``: the wires, the parts and the schematic.

    Parameters
    ----------
    rig : labrig.io.config.RigConfig
        A rig file's contents (:func:`load_rig`); its ``[bridge] firmware`` picks the
        MS150 DAC stage or the H-bridge + encoder bench, and its H-bridge options (drive
        mode, current sense) the wires.
    board : {"uno", "nano", "mega"}, optional
        The Arduino the firmware is built for (default: the rig file's ``bridge.board``,
        else the Uno).

    Returns
    -------
    labrig.bridge.wiring.Wiring
        ``.to_pandas()`` the wiring table, ``.bom()`` the bill of materials,
        ``.plot(ax)`` the schematic, ``.save(folder)`` all of them as files.

    Examples
    --------
    >>> import labrig.verbs as lr
    >>> w = lr.wiring(lr.load_rig("configs/rig_arduino_hbridge.toml"))
    >>> w.to_pandas().loc[0, ["signal", "pin", "function"]].tolist()
    ['PWM / IN1', 'D9', 'OC1A']
    """
    from labrig.bridge.wiring import wiring as _wiring

    return _wiring(rig, board=board)


def ports(probe=()):
    """The serial ports, the Arduino-class ones greeted and the labrig bridges marked
    (``labrig ports``).

    Parameters
    ----------
    probe : sequence of str
        Devices to greet whatever they are (an emulator's pty).

    Returns
    -------
    list of labrig.bridge.ports.Port
    """
    from labrig.bridge.ports import list_ports

    return list_ports(probe)


def find_board(board_id=None) -> str:
    """The device of the one labrig board connected, or of the board whose id is
    ``board_id`` (what ``--port`` defaults to).

    Parameters
    ----------
    board_id : int or str, optional
        The board's id (8 hex digits, as ``labrig ports`` shows it).

    Raises
    ------
    UserError
        None is connected, or several are (naming them), or none has that id.
    """
    from labrig.bridge.ports import list_ports, the_board

    return the_board(list_ports(), _as_board_id(board_id))


def format_board_id(board_id) -> str:
    """A board id as labrig shows it (8 hex digits; ``"-"`` for none)."""
    from labrig.bridge.protocol import format_board_id as fmt

    return fmt(board_id)


def board_id(text) -> int:
    """A board id as a number, from its 8 hex digits (as ``labrig ports`` shows it).

    Raises
    ------
    UserError
        Not a board id.

    Examples
    --------
    >>> hex(board_id("3F2A91C0"))
    '0x3f2a91c0'
    """
    return _as_board_id(text)


def _as_board_id(value) -> int | None:
    """``value`` (None, an int or 8 hex digits) as a board id (the verbs take either)."""
    from labrig.bridge.identity import parse_board_id

    return value if value is None or isinstance(value, int) else parse_board_id(value)


def flash(board: str, rig=None, *, port: str | None = None, programmer: str | None = None,
          build: bool | None = None):
    """Upload the bridge firmware for ``board`` and the rig through avrdude, then greet the
    board (``labrig flash``).

    Parameters
    ----------
    board : {"uno", "nano", "nano-old", "mega"}
        The Arduino (``nano-old``: a Nano with the old 57600-baud bootloader).
    rig : RigConfig or path, optional
        The rig whose firmware (its ``[bridge]``); default the MS150 bridge.
    port : str, optional
        The board's serial device; default the one Arduino-class USB port connected.
    programmer : str, optional
        An avrdude programmer instead of the bootloader (``usbasp``...).
    build : bool, optional
        Build the image from ``firmware/`` (True) or take the packaged one (False); default
        build when the AVR toolchain is installed.

    Returns
    -------
    labrig.bridge.flash.FlashResult
    """
    from labrig.bridge.flash import flash as _flash
    from labrig.verbs.data import load_rig

    if rig is not None and not hasattr(rig, "bridge"):
        rig = load_rig(rig)
    return _flash(board, rig, port, programmer=programmer, build=build)


def doctor(port: str | None = None, rig=None, *, baud: int = 500000, board_id=None,
           seconds: float = 2.0):
    """Check the chain from this PC to the rig's sensors, one link at a time
    (``labrig doctor``): the port and its permissions, who holds it, the greeting and its
    baud rate, the firmware, the board against the rig file, the board's id, 0 V out with
    every sensor at rest, and the sample rate over a run of ``seconds`` at 0 V.

    Parameters
    ----------
    port : str, optional
        The board's serial device; default the one labrig board connected.
    rig : RigConfig or path, optional
        The rig file the board should match (default the MS150 rig).
    baud : int
        The serial speed (the firmware's build-time BAUD).
    board_id : int or str, optional
        The board the station is bound to.
    seconds : float
        The run at 0 V.

    Returns
    -------
    labrig.bridge.doctor.ChainReport
        ``str(report)``: a line per check; ``report.ok``: all passed.
    """
    from labrig.bridge.doctor import check_chain
    from labrig.verbs.data import load_rig

    if rig is not None and not hasattr(rig, "bridge"):
        rig = load_rig(rig)
    board_id = _as_board_id(board_id)
    return check_chain(port, rig, baud=baud, board_id=board_id, seconds=seconds)
