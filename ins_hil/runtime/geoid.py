"""The EGM96 geoid moved to :mod:`ins_hil.geoid` (the lowest layer: drivers and the simulator use it too);
this name re-exports it."""

from ins_hil.geoid import msl_height, undulation

__all__ = ["msl_height", "undulation"]
