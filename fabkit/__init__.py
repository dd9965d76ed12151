"""fabkit: design flat active sheets that morph into several 3D shapes, and fabricate them.

Data flows one way::

    spec -> surfaces + material -> solve -> design -> check / plot -> toolpath -> export -> machine
"""

from fabkit.errors import FabkitError

__version__ = "0.1.0"
__all__ = ["FabkitError", "__version__"]
