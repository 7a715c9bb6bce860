//! Analytic test shapes as voxel-boundary quad meshes and marching-cubes triangle meshes.
