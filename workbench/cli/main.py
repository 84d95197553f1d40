"""The ``workbench`` command line.

Each command lives in ``workbench/commands/<name>.py`` and offers
``register(subparsers)`` and ``run(args) -> int``. Exit status: 0 ok (data
warnings are printed, one line each, and do not fail), 2 bad input (one line,
no traceback), 1 internal error.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import warnings

from workbench.core.errors import DataWarning, InputError

COMMANDS = (
    "info",
    "simulate",
    "frf",
    "run",
    "sweep",
    "identify",
    "modes",
    "minimality",
    "compare",
    "diagnose",
    "augment",
    "design",
    "loop",
    "regress",
    "update",
    "predict",
    "modalfit",
    "import",
    "export",
    "report",
)
# a command whose module is not named as the command (``import`` is a Python keyword)
MODULES = {"import": "import_data"}


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's own usage errors are bad input too: exit 2, one line
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The command-line parser; with ``only``, just that command's subparser.

    A command imports its own dependencies (scipy.signal, matplotlib, ...): building
    every subparser costs ~1 s of imports, so :func:`main` builds only the command
    it was given and the full parser for ``--help`` or an unknown command.
    """
    parser = _Parser(
        prog="workbench",
        description=(
            "Control-design workbench for rigid-flexible motion systems: simulate experiments, "
            "estimate FRFs, identify modal models, compare models with measurements and "
            "diagnose which physical effect a model is missing."
        ),
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMANDS if only is None else (only,):
        # every listed command must import: a broken import fails loudly, it is never
        # turned into a missing command
        module = importlib.import_module(f"workbench.cli.commands.{MODULES.get(name, name)}")
        p = module.register(sub)
        p.set_defaults(_run=module.run)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None):
    text = " ".join(str(message).split())
    label = "warning" if issubclass(category, DataWarning) else category.__name__
    print(f"{label}: {text}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    command = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(command if command in COMMANDS else None)
    args = parser.parse_args(argv)
    with warnings.catch_warnings():
        warnings.simplefilter("always", DataWarning)
        warnings.showwarning = _show_warning
        try:
            status = args._run(args)
        except InputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            return 130
        except BrokenPipeError:
            # the reader went away (``workbench compare ... | head``): not an error of ours;
            # point stdout at devnull so the interpreter's final flush does not fail again
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            return 141  # 128 + SIGPIPE, as a shell reports it
        except Exception as exc:  # an internal error: one line unless debugging
            if os.environ.get("WORKBENCH_DEBUG"):
                raise
            print(
                f"internal error: {type(exc).__name__}: {' '.join(str(exc).split())} "
                "(set WORKBENCH_DEBUG=1 for the traceback)",
                file=sys.stderr,
            )
            return 1
    return int(status or 0)


if __name__ == "__main__":
    sys.exit(main())
