"""A board's own id: given once by a host at a greeting and kept in the board's EEPROM
(firmware 2.3), so a station bound to it (``--board-id``) finds its bench's board whatever
port the system gave it, and two benches on one PC never swap.

The id is 32 bits, shown as 8 hex digits (``3F2A91C0``); 0 means none given yet. A board
never replaces an id it has; flashing keeps it (avrdude writes the flash, not the EEPROM).
"""
from __future__ import annotations

import re
import secrets

from labrig.core.errors import RigError, UserError

#: the first firmware that keeps an id
FIRST_VERSION = (2, 3, 0)


def parse_board_id(text: str) -> int:
    """A board id given by a user (8 hex digits, as ``labrig ports`` shows it).

    Raises
    ------
    UserError
        Not 1-8 hex digits, or 0.
    """
    t = str(text).strip()
    if not re.fullmatch(r"(0x)?[0-9A-Fa-f]{1,8}", t) or int(t, 16) == 0:
        raise UserError(f"board_id: {text!r} is not a board id (8 hex digits, as labrig ports "
                        "shows it, e.g. 3F2A91C0)")
    return int(t, 16)


def new_board_id() -> int:
    """A fresh id (random, never 0)."""
    return secrets.randbits(32) or 1


def settle(ask, version: tuple, *, expected: int | None = None, port: str = "",
           assign: bool = True) -> int | None:
    """The board's id, giving it one when it has none (and ``assign``).

    Parameters
    ----------
    ask : callable
        ``ask(body) -> int | None``: send BOARD_ID with ``body`` and return the id the board
        answers with (None: no answer, or refused by a firmware before 2.3).
    version : tuple
        The board's firmware version.
    expected : int, optional
        The id the station is bound to.
    port : str
        For messages.
    assign : bool
        Give a board without an id one (a listing only reads).

    Returns
    -------
    int or None
        None for a firmware that keeps no id.

    Raises
    ------
    RigError
        The board is not the one ``expected`` names, or cannot say which it is.
    """
    from labrig.bridge.protocol import format_board_id, id_body

    have = ask(b"") if version >= FIRST_VERSION else None
    if have == 0 and assign:
        have = ask(id_body(new_board_id()))
    if expected is not None and have != expected:
        if have is None:
            raise RigError(f"the board on {port} cannot say which it is (firmware "
                           f"{'.'.join(map(str, version))}; ids from "
                           f"{'.'.join(map(str, FIRST_VERSION))}): flash it (labrig flash), or "
                           "leave out `board_id`")
        raise RigError(f"the board on {port} is {format_board_id(have)}, not "
                       f"{format_board_id(expected)} (`board_id`): is this bench's board on "
                       "another port? labrig ports lists them")
    return have
