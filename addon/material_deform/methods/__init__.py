"""The solver methods behind the one panel, and their registry.

A method is one module here that defines a subclass of :class:`Method` and registers an
instance with :func:`register_method`. The session never branches on the method: it gathers the
common inputs (mesh, anchors, stiffness), asks the active method to add what it needs, to build a
solver, and to solve for the current anchor transforms. A fifth method is one more module,
imported below.
"""

from .base import (  # noqa: I001  (unsorted: the methods below come in menu order)
    Method,
    Result,
    all_methods,
    convergence_status,
    enum_items,
    get,
    register_method,
    unregister_method,
)

# registration order is the menu's order; the first method is the default
from . import material  # noqa: F401  (registers itself)
from . import edge  # noqa: F401  (registers itself)
from . import pose_space  # noqa: F401  (registers itself)
from . import pyramid  # noqa: F401  (registers itself)

__all__ = [
    "Method",
    "Result",
    "all_methods",
    "convergence_status",
    "enum_items",
    "get",
    "register_method",
    "unregister_method",
]
