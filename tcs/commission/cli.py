"""The ``tcs-commission`` command line: options, dispatch, output, exit codes.

Every subcommand lives in its own module with ``add_parser(subparsers, parents)`` and
``run(args, config) -> Outcome``; this module parses, loads the hardware file (a bad file is
listed key by key, exit 2), runs the subcommand and prints its :class:`Outcome` — text on
stdout (errors on stderr), or one JSON object on stdout with ``--json``. Subcommands never
print; progress goes to stderr (a bar on a terminal, a plain line every 10 s elsewhere). Help
texts come from the modules' docstrings without their RST markup; a ``--`` before a negative
distance may be followed by options (``jog zd -- -5 --speed 2``). The usage is in the package
docstring (:mod:`tcs.commission`).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import re
import signal
import sys

from tcs import __version__
from tcs.commission import home, info, jog, limits, pointing, scan
from tcs.commission.common import CommissionError, ExitCode, Outcome, exit_code_of
from tcs.config import DEFAULT_CONFIG, load_config
from tcs.errors import ConfigErrors, TcsError

PROG = "tcs-commission"
COMMANDS = {"scan": scan, "info": info, "home": home, "limits": limits, "jog": jog,
            "pointing": pointing}


def common_options() -> argparse.ArgumentParser:
    """Options every subcommand takes (after the subcommand's name)."""
    p = argparse.ArgumentParser(add_help=False)
    g = p.add_argument_group("common options")
    g.add_argument("--config", default=str(DEFAULT_CONFIG),
                   help="hardware file (default: %(default)s)")
    g.add_argument("--json", action="store_true", help="print one JSON object for scripts")
    sim = g.add_mutually_exclusive_group()
    sim.add_argument("--simulate", dest="simulate", action="store_true", default=None,
                     help="start the file's [simulation] drives in this process (default: when "
                          "[can] is virtual and the file has [simulation])")
    sim.add_argument("--no-simulate", dest="simulate", action="store_false",
                     help="never start simulated drives")
    g.add_argument("--force", action="store_true",
                   help="go on although another master (tcs-server?) is seen on the bus; "
                        "pointing: fit although there are fewer than 3 samples per term; "
                        "limits --write: also widen the file's limits to the proposal")
    g.add_argument("--log-level", default="ERROR",
                   choices=["DEBUG", "INFO", "WARNING", "ERROR"], help="log to stderr (default ERROR)")
    return p


_RST_ROLE = re.compile(r":[a-z]+:`~?([^`]*)`")


def plain(text: str) -> str:
    """Docstring text for a terminal: no RST roles or literal backquotes."""
    return _RST_ROLE.sub(r"\1", text).replace("``", "")


class PlainHelpFormatter(argparse.HelpFormatter):
    """Help built from the modules' docstrings, without their RST markup."""

    def _format_text(self, text):
        return super()._format_text(plain(text))

    def _expand_help(self, action):
        return plain(super()._expand_help(action))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, description="Commission the drives of a hardware file: scan the bus, "
        "reference, find limits, jog, fit a pointing model. Stop tcs-server first.",
        epilog="exit codes: 0 ok, 1 operation failed, 2 usage or configuration error, "
               "3 hardware not found or not responding", formatter_class=PlainHelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    parents = [common_options()]
    for module in COMMANDS.values():
        module.add_parser(subparsers, parents)
    for sub in subparsers.choices.values():
        sub.formatter_class = PlainHelpFormatter
    return parser


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def normalize_argv(argv: list[str]) -> list[str]:
    """``jog zd -- -5 --speed 2``: a ``--`` only there to protect a negative number is dropped,
    so options may still follow (argparse reads ``-5`` as a value by itself: no option of
    tcs-commission looks like a number)."""
    out = []
    for i, arg in enumerate(argv):
        if arg == "--" and i + 1 < len(argv) and _is_number(argv[i + 1]):
            continue
        out.append(arg)
    return out


def _clean(value):
    """JSON cannot carry inf / nan: make them null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def emit(outcome: Outcome, as_json: bool, stdout=None, stderr=None) -> None:
    """Print an outcome: JSON, or the text lines and the error."""
    stdout = stdout or sys.stdout
    stderr = stderr or sys.stderr
    if as_json:
        stdout.write(json.dumps(_clean(outcome.as_json()), indent=2, default=str) + "\n")
        return
    for line in outcome.lines:
        stdout.write(line + "\n")
    if outcome.error:
        stderr.write(f"{PROG} {outcome.command}: {outcome.error}\n")


def _interrupt_on_sigterm():
    """SIGTERM ends a subcommand like Ctrl-C (drives disabled on the way out); the old handler."""
    def handler(signum, frame):
        raise KeyboardInterrupt
    try:
        return signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread (called from a worker thread): leave it alone
        return None


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand; returns the exit code (see :class:`ExitCode`)."""
    parser = build_parser()
    try:
        args = parser.parse_args(normalize_argv(list(sys.argv[1:] if argv is None else argv)))
    except SystemExit as exc:  # argparse: --help (0) or a usage error (2)
        return int(exc.code or 0)
    # Log to stderr for the duration of this call only (main() is also called in-process).
    root = logging.getLogger()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    handler.setLevel(getattr(logging, args.log_level))
    old_level = root.level
    root.addHandler(handler)
    root.setLevel(min(old_level or logging.WARNING, handler.level))
    logging.getLogger("can.interfaces.socketcand").setLevel(logging.ERROR)
    previous_term = _interrupt_on_sigterm()
    outcome = Outcome(args.command)
    try:
        config = load_config(args.config)
        outcome = COMMANDS[args.command].run(args, config)
    except ConfigErrors as exc:
        outcome.fail(f"the hardware file is not valid:\n{exc.message}", ExitCode.USAGE)
    except CommissionError as exc:
        outcome.data.update(exc.data)
        outcome.fail(exc.message, exc.exit_code)
    except TcsError as exc:
        outcome.fail(exc.message or str(exc), exit_code_of(exc))
    except KeyboardInterrupt:
        outcome.fail("interrupted (drives disabled)", ExitCode.FAILED)
    finally:
        root.removeHandler(handler)
        root.setLevel(old_level)
        if previous_term is not None:
            signal.signal(signal.SIGTERM, previous_term)
    emit(outcome, args.json)
    return int(outcome.exit_code)


if __name__ == "__main__":
    sys.exit(main())
