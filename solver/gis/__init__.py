"""Results that GIS tools can use: ground/image transforms, RPC export, GeoJSON (issue 16)."""
