"""Point-cloud writers beyond lidard.pointcloud's PLY/LAS/NPZ: PCD (PCL/Open3D) and MCAP (Foxglove)."""
