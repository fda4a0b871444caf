"""Roads on a map: WGS 84 projection, road networks, HMM map matching, linear referencing and the files a
GIS opens (GeoJSON, GeoPackage, linear-reference CSV, OpenCRG) and the offline web map."""
