"""Paired evaluation of controllers under the same random disturbances (``ptrack evaluate``)."""
