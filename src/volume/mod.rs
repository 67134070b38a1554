//! Volumes: regular grids with an index-to-world affine, scalar and vector fields, trilinear sampling.
