"""``python -m train.train``: the same as ``ptrack train`` (:mod:`train.cli`)."""

import sys

from train.cli import run_command

if __name__ == "__main__":
    sys.exit(run_command("train"))
