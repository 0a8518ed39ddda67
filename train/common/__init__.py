"""What every job of :mod:`train` shares: statistics, the run-folder harness, config files,
command-line arguments generated from config dataclasses, one-thread defaults."""
