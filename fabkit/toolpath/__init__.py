"""From a design (or a director field) to toolpaths: print lines, encoding, channels.

The data model (:mod:`fabkit.toolpath.model`) is the contract with the output writers.
"""

from fabkit.toolpath.model import (
    PRINT,
    TRAVEL,
    Layer,
    Move,
    Toolpath,
    load_toolpath,
    save_toolpath,
)

__all__ = ["PRINT", "TRAVEL", "Layer", "Move", "Toolpath", "load_toolpath", "save_toolpath"]
