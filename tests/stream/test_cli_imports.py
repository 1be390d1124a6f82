"""``robocal --help`` stays fast: building the parser loads none of the heavy libraries.

Every command module imports torch, pinocchio, pandas, zenoh, rerun and optuna where it uses them
(inside ``take_action``), so a command added later that imports one at module level fails here.
"""

import subprocess
import sys

HEAVY = ("torch", "pinocchio", "zenoh", "rerun", "optuna", "pandas", "matplotlib", "scipy")

PROBE = """
import sys
from stream.cli import build_parser
parser = build_parser()
for action in parser._subparsers._group_actions:  # every command's own parser too
    for sub in action.choices.values():
        sub.format_help()
print(" ".join(sorted(m for m in {heavy!r} if m in sys.modules)))
"""


def test_building_the_parser_imports_no_heavy_library():
    out = subprocess.run(
        [sys.executable, "-c", PROBE.format(heavy=HEAVY)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    assert out.stdout.split() == [], f"imported while building the parser: {out.stdout}"


def test_help_exits_zero_and_lists_every_command():
    out = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from stream.cli import main; sys.exit(main(['--help']))",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    for command in ("sim", "train", "hpo", "gap", "run", "replay", "demo"):
        assert command in out.stdout
