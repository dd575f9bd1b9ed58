"""Face meshes and what is placed on them: landmarks, marker layouts, regions, geodesics."""

from mocap.mesh.mesh import (
                             MESH_FORMATS,
                             Mesh,
                             boundary_loops,
                             degenerate_faces,
                             face_normals,
                             load_mesh,
                             save_obj,
                             vertex_normals,
)

__all__ = ["Mesh", "MESH_FORMATS", "load_mesh", "save_obj", "vertex_normals", "face_normals",
           "boundary_loops", "degenerate_faces"]
