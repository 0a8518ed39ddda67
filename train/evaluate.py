"""``python -m train.evaluate``: the same as ``ptrack evaluate`` (:mod:`train.cli`)."""

import sys

from train.cli import run_command

if __name__ == "__main__":
    sys.exit(run_command("evaluate"))
