"""The ``robocal`` command line: one entry point, one small class per command.

Each command parses its arguments, calls one library function and prints the result (``--json``
for a machine-readable result on stdout). Exit 0 on success, 2 on bad input with a one-line
reason (``--debug`` shows the traceback).

    robocal sim dataset --scenario paper --n 3004 --seed 0 --out data.parquet
    robocal data summary data.parquet --json
"""

from __future__ import annotations

import argparse
import sys

from kinematics.errors import RobocalError
from stream.cli._base import CLIUsageError, Command, check_outputs
from stream.cli.data import COMMANDS as _DATA
from stream.cli.gap import COMMANDS as _GAP
from stream.cli.hpo import COMMANDS as _HPO
from stream.cli.learn import COMMANDS as _LEARN
from stream.cli.line import COMMANDS as _LINE
from stream.cli.report import COMMANDS as _REPORT
from stream.cli.run import COMMANDS as _RUN
from stream.cli.sim import COMMANDS as _SIM

_COMMANDS: tuple[type[Command], ...] = (
    *_DATA,
    *_SIM,
    *_LEARN,
    *_HPO,
    *_GAP,
    *_RUN,
    *_REPORT,
    *_LINE,
)


def build_parser() -> argparse.ArgumentParser:
    """The full parser; commands with two words (``data summary``) become nested parsers."""
    parser = argparse.ArgumentParser(prog="robocal", description=__doc__.splitlines()[0])
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    parser.add_argument(
        "--torch-threads",
        type=int,
        default=1,
        help="torch and BLAS threads for training and prediction (default 1, as the daemon: "
        "a shared machine runs many times slower with more)",
    )
    top = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    groups: dict[str, argparse._SubParsersAction] = {}
    for cls in _COMMANDS:
        words = cls.name.split()
        sub = top
        if len(words) == 2:
            if words[0] not in groups:
                group = top.add_parser(words[0], help=f"{words[0]} commands")
                groups[words[0]] = group.add_subparsers(dest="subcommand", required=True)
            sub = groups[words[0]]
        command = cls()
        p = sub.add_parser(words[-1], help=cls.help, description=cls.help)
        command.add_arguments(p)
        p.set_defaults(_command=command)
    return parser


def _cap_threads(n: int, uses_torch: bool = True) -> None:
    """Cap torch's intra-op threads (CLIUsageError below 1); torch is not loaded for commands
    that do not use it."""
    if n < 1:
        raise CLIUsageError(f"--torch-threads must be >= 1, got {n}")
    if not uses_torch:
        return
    # every learning command imports torch anyway; --help does not get here
    from learner.training import set_compute_threads

    set_compute_threads(n)


def main(argv: list[str] | None = None) -> int:
    """Run one command; errors become one line on stderr and exit code 2."""
    args = build_parser().parse_args(argv)
    try:
        check_outputs(args)
        _cap_threads(args.torch_threads, args._command.uses_torch)
        return args._command.take_action(args)
    except RobocalError as exc:  # CLIUsageError included
        if args.debug:
            raise
        print(f"robocal: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a full disk, permissions, a path that is a file: one line too
        if args.debug:
            raise
        from stream.state import describe_os_error

        print(f"robocal: error: {describe_os_error(exc)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
