"""The deliver stage: the fused floor as the files a surveyor's client opens (DXF, IFC, PLY mesh, the
GeoJSON's .prj) and every room's cloud in the floor frame."""
