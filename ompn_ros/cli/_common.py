"""What every ``ompn_*`` command shares: the parser style and one way of reporting known errors.

A known error (:data:`ompn_ros.errors.KNOWN_ERRORS`: the package's own errors, ``OMPNError``, and the
``OSError`` s a path given by the user raises) is printed as one line ``<prog>: error: <message>``
on stderr and the command exits with code 2; ``--debug`` shows the traceback instead.  Anything
else, a plain ``ValueError`` included, is a bug and keeps its traceback.  Ctrl-C prints one line
(what was kept, for ``ompn_train``: :mod:`ompn_ros.train.interrupt`) and exits with code 130.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

from ompn_ros.errors import KNOWN_ERRORS, error_line

Body = Callable[[argparse.Namespace], int]
INTERRUPTED = 130
"""Exit code after Ctrl-C (128 + SIGINT, what a shell reports for a process SIGINT ended)."""


class _Formatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Defaults shown after every help text (the description keeps its line breaks).

    An option without a value to show (a flag, a required option, a default of None) has none
    appended: its help says what happens without it (:func:`missing_default_texts` checks that).
    """

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default in (None, False) or action.required:
            return action.help
        return super()._get_help_string(action)


def missing_default_texts(parser: argparse.ArgumentParser) -> list[str]:
    """Options whose help text neither shows a default nor explains the behaviour without them."""
    missing = []
    grouped = {id(a) for g in parser._mutually_exclusive_groups if g.required for a in g._group_actions}
    for action in parser._actions:
        if not action.option_strings or action.required or id(action) in grouped:
            continue
        text = (action.help or "").lower()
        if action.default is None and not any(word in text for word in ("default", "none", "without")):
            missing.append(action.option_strings[-1])
        elif not action.help:
            missing.append(action.option_strings[-1])
    return missing


def make_parser(prog: str, description: str | None) -> argparse.ArgumentParser:
    """An argument parser showing defaults, with ``--debug`` (tracebacks instead of one-line errors)."""
    parser = argparse.ArgumentParser(
        prog=prog, description=_plain(description or ""), formatter_class=_Formatter
    )
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error")
    return parser


def _plain(text: str) -> str:
    """Docstring text without reStructuredText markup (double backquotes, ``::``)."""
    return text.replace("``", "").replace("::", ":")


def run_cli(
    parser: argparse.ArgumentParser,
    body: Body,
    argv: Sequence[str] | None = None,
) -> int:
    """Parse ``argv``, run ``body(args)`` and turn a known error into one line on stderr and exit code 2.

    ``args.command_line`` is the command as run (for provenance records): the parser's ``prog`` and
    its arguments.
    """
    args = parser.parse_args(None if argv is None else list(argv))
    args.command_line = [parser.prog, *(sys.argv[1:] if argv is None else argv)]
    try:
        return body(args)
    except KNOWN_ERRORS as exc:
        if getattr(args, "debug", False):
            raise
        print(f"{parser.prog}: error: {error_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        if getattr(args, "debug", False):
            raise
        print(f"{parser.prog}: {error_line(exc) if str(exc) else 'interrupted'}", file=sys.stderr)
        return INTERRUPTED
