"""matdeform: mesh deformation solvers with a numpy API: material-aware deformation (Popa,
Julius, Sheffer 2006), edge-based iterative material deformation (cloth, membranes, shells),
pose-space surface manipulation from example shapes and shape-preserving pyramid coordinates.

numpy in, numpy out; the solvers are a compiled C++ core (Eigen + CHOLMOD). Never imports bpy.
"""

from . import shapes  # procedural test and demo meshes: md.shapes.tube(...)
from .deformer import MaterialDeformer
from .edge import EdgeDeformer
from .frames import deformation_gradients
from .learn import (
    learn_distortions,
    learn_stiffness,
    rotation_spread,
    smooth_distortions,
    stiffness_from_distortion,
)
from .mesh import (
    boundary_and_nonmanifold_edges,
    dual_edges,
    face_components,
    faces_inside,
    mesh_edges,
)
from .obj import read_obj, write_obj
from .pose_space import PoseSpaceDeformer
from .pyramid import PyramidDeformer, pyramid_coordinates
from .stiffness import bend_from_shear, bend_from_vertex, shear_from_vertex
from .threads import num_threads, set_num_threads
from .transforms import (
    ROTATION_VECTOR_TOLERANCE,
    blend_transforms,
    polar_decompose,
    transform_exp,
    transform_log,
    unwrap_rotations,
)
from .weights import harmonic_weights

__version__ = "0.1.0"

__all__ = [
    "ROTATION_VECTOR_TOLERANCE",
    "EdgeDeformer",
    "MaterialDeformer",
    "PyramidDeformer",
    "PoseSpaceDeformer",
    "bend_from_shear",
    "bend_from_vertex",
    "blend_transforms",
    "boundary_and_nonmanifold_edges",
    "deformation_gradients",
    "dual_edges",
    "face_components",
    "faces_inside",
    "harmonic_weights",
    "num_threads",
    "learn_distortions",
    "learn_stiffness",
    "mesh_edges",
    "polar_decompose",
    "pyramid_coordinates",
    "read_obj",
    "rotation_spread",
    "set_num_threads",
    "shapes",
    "shear_from_vertex",
    "smooth_distortions",
    "stiffness_from_distortion",
    "transform_exp",
    "transform_log",
    "unwrap_rotations",
    "write_obj",
]
