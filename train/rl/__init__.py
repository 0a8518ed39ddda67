"""Stable-Baselines3 training of pure and residual policies (``ptrack train``, ``ptrack
campaign``, ``ptrack study``)."""
