"""The command line: parse arguments, call the core, map errors to exit codes.

Exit codes (docs/design.md, 'Exit codes'): 0 success, 2 user error, 1 rig or runtime fault,
130 interrupted. This is the only place that turns exceptions into exit codes.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import traceback

from labrig.core.version import __version__
from labrig.core.errors import LabrigError, Terminated, UserError


class _TrustCode(argparse.Action):
    """``--trust-code FILE.py``: data files read by this command may name effects from
    FILE.py (a user effect is code that runs; see labrig.model.effects.trust_code)."""

    def __call__(self, parser, namespace, values, option_string=None):
        from labrig.model.effects import trust_code

        trust_code([values])
        getattr(namespace, self.dest, None) or setattr(namespace, self.dest, [])
        getattr(namespace, self.dest).append(values)


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's own errors are user errors too: exit 2
        self.print_usage(sys.stderr)
        raise UserError(message)


#: ``labrig --help``: the order of work, above the list of commands
DESCRIPTION = """\
DC-servo lab: acquire, analyse, identify, diagnose.

The order of work (sweep/import -> analyse -> identify -> diagnose -> propose):
  1. sweep / import   record runs on the rig (sweep --sim or --port), or bring a
                      scope/DAQ export in as runs (import)
  2. analyse          deadband, Km, tau_m and the gain-vs-amplitude verdict
  3. identify         fit the plant (+ effects): a model file (-o model.json)
  4. diagnose         where the model fails, which effect is missing (--auto: to
                      the end)
  5. propose          the experiment that tells two explanations apart; sweep
                      it, then diagnose the old and the new runs together
All five in the browser, watching each run come in: labrig lab --sim"""

#: ``labrig --help``: below the list of commands
EPILOG = """\
Each command's own options: labrig COMMAND --help (e.g. labrig identify --help).
Every command also takes --debug and --trust-code FILE.py, listed last in its help."""


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="labrig", description=DESCRIPTION, epilog=EPILOG,
                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"labrig {__version__}")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    import labrig.commands  # noqa: F401  (registers the subcommands)
    from labrig.commands.registry import COMMANDS
    from labrig.model.effects import reset_trust

    reset_trust()  # trust is given per command line, never carried over

    for name, (func, help_) in COMMANDS.items():
        sp = sub.add_parser(name, help=help_, description=(func.__doc__ or help_).strip())
        func.configure(sp)
        _common_options(sp)
        _names_in_any_case(sp)
        sp.set_defaults(func=func)
    return p


def _common_options(parser: argparse.ArgumentParser, nested: bool = False) -> None:
    """The options every command takes, last in its help, after its own; a nested
    subcommand (``class serve``) takes them too, and says them only when given there
    (argparse's defaults of a nested parser would undo ``labrig class --debug serve``)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _common_options(sub, nested=True)
    unset = {"default": argparse.SUPPRESS} if nested else {}
    parser.add_argument("--debug", action="store_true", help="show tracebacks", **unset)
    parser.add_argument("--trust-code", action=_TrustCode, metavar="FILE.py",
                        help="let the model, rig or config files this command reads name user "
                             "effects from FILE.py. A user effect is Python code and runs "
                             "with your rights: pass only files you have read (repeatable)",
                        **unset)


def _names_in_any_case(parser: argparse.ArgumentParser) -> None:
    """Options whose value is one of a list of lower-case names (``--method jfo``,
    ``--through loop``) take it in any case (``--method JFO``); the command sees the
    lower-case name. Walks nested subcommands too (``mystery new``)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                _names_in_any_case(sub)
        elif (action.choices and action.type is None
              and all(isinstance(c, str) and c == c.lower() for c in action.choices)):
            action.type = str.lower


def main(argv=None) -> int:
    """Run one command line; return its exit code (see the module's docstring).

    SIGTERM and SIGHUP are caught from the first line on, before the slow imports
    (:func:`_stop_on_signals`); the handlers found are back when this returns.
    """
    from labrig.core.memory import keep_freed_memory
    from labrig.core.parallel import one_blas_thread

    one_blas_thread()   # before numpy is imported
    old = _stop_on_signals()
    keep_freed_memory()
    try:
        return _main(argv)
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def _stop_on_signals() -> dict:
    """Until a command installs its own (``labrig sweep`` stops the board first), a
    SIGTERM or SIGHUP ends labrig at once with one line and exit 128 + signal number, as
    a shell reports it (143, 129), instead of a silent death by the signal; from the
    first moments, while Python still imports the scientific stack.

    The handler exits where it lands (``os._exit``), like the default action it replaces:
    an exception could be swallowed by a command's ``except Exception``. A signal that is
    ignored (``nohup``) or already handled by the caller stays so; outside the main
    thread nothing is installed. Returns the handlers replaced, to put back.
    """
    import threading

    if threading.current_thread() is not threading.main_thread():
        return {}
    old = {}
    for sig in (signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(sig) == signal.SIG_DFL:
            old[sig] = signal.signal(sig, _exit_on_signal)
    return old


def _exit_on_signal(signum, frame):
    for sig in (signal.SIGTERM, signal.SIGHUP):  # one line, even if a second one comes
        signal.signal(sig, signal.SIG_IGN)
    try:
        helper = sys.modules.get("labrig.step_helper")
        if helper is not None:
            helper.kill_now()
        print(f"labrig: {Terminated(signum)}", file=sys.stderr, flush=True)
    finally:
        os._exit(128 + signum)


def _main(argv=None) -> int:
    from labrig.core.errors import Interrupted

    argv = sys.argv[1:] if argv is None else argv
    debug = "--debug" in argv
    # figures go to files: the command line picks the file backend, the library never
    # does (a notebook keeps its inline backend); through the environment, so a command
    # that draws nothing never pays matplotlib's import
    if "matplotlib" in sys.modules:
        sys.modules["matplotlib"].use("Agg")
    else:
        os.environ["MPLBACKEND"] = "Agg"
    if not debug:  # wild candidates overflow on purpose during a search; not news for users
        import warnings

        warnings.simplefilter("ignore", RuntimeWarning)
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help(sys.stderr)
            return 2
        if getattr(args.func, "fits", False):
            import labrig.step_helper as step_helper   # python-control, on the other core

            step_helper.start()
        return int(args.func(args) or 0)
    except KeyboardInterrupt as exc:
        # (the output is at 0 V unless the sweep could not set it: then that is said)
        print(f"labrig: interrupted; finished runs are kept, {_notes(exc) or 'the output is at 0 V'}",
              file=sys.stderr)
        return 130
    except Interrupted as exc:   # SIGTERM/SIGHUP (errors.Terminated): one line, 128 + signal
        print(f"labrig: {_as_typed(exc)}", file=sys.stderr)
        return exc.exit_code
    except LabrigError as exc:
        if debug:
            traceback.print_exc()
        print(f"labrig: error: {_as_typed(exc)}", file=sys.stderr)
        return exc.exit_code
    except BrokenPipeError:
        return 1
    except Exception as exc:  # a bug: say so plainly, keep the traceback behind --debug
        if debug:
            traceback.print_exc()
        print(f"labrig: internal error: {type(exc).__name__}: {_as_typed(exc)} "
              "(rerun with --debug and report it)", file=sys.stderr)
        return 1


def _as_typed(exc: BaseException) -> str:
    """A library error's text with its Python parameters named as the options typed
    ("`method`" -> "--method"; :func:`labrig.commands.options.translate`)."""
    from labrig.commands.options import translate

    notes = _notes(exc)
    return translate(f"{exc} -- {notes}" if notes else str(exc))


def _notes(exc: BaseException) -> str:
    """What was added to an error on its way out (a sweep's failed zero), on one line."""
    return "; ".join(" ".join(str(n).split()) for n in getattr(exc, "__notes__", ()))


def run() -> None:
    """The console entry point: ``main()``, then end the process at once.

    Every output is written and closed when ``main`` returns (files atomically, emulators
    and pools ended by their own ``with`` blocks); the interpreter's teardown of numba,
    LLVM and the scientific stack would only add 0.5-0.8 s to every command.
    """
    import os

    from labrig.core.timing import mark
    import labrig.step_helper as step_helper

    step_helper.allow()   # a fresh process, no thread yet: commands may fork their helper
    code = main()
    step_helper.stop()
    mark("exit")
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
