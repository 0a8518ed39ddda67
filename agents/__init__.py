"""Controllers, residual wrappers and policy adapters for ptrack_gym environments."""
