"""Built-in linear elastic analysis on voxel hexahedra (scikit-fem), for stress-driven infill."""
