"""The file layer: every file format the library reads or writes, one verb pair (`read_*` / `write_*`) each.

* `points`: point clouds (text, LAS/LAZ, PLY, NPZ; GeoTIFF/BAG grids read as soundings) behind one
  format table (`read_points`, `write_points`, `iter_chunks`), float64 georeferenced coordinates;
* `crs`: CRSs through pyproj (their spelling, the UTM zone of lon/lat data, lon/lat of positions);
* `annotations`: scene and detection JSON documents, validated on read and write;
* `scenes`: the scene file pair (`{scene}.npz` soundings + `{scene}.json` annotations);
* `templates`: template scan files of the model-based detector;
* `export`: detections as CSV (+ JSON sidecar) and GeoJSON (RFC 7946 and in the survey's CRS);
* `openpcdet`: the synthetic dataset in OpenPCDet's custom-dataset layout;
* `atomic`: atomic writes; `origin`: local origins for float32 work on georeferenced coordinates.

This package imports only numpy, the file libraries it needs (pandas, laspy, trimesh, pyproj, rasterio,
pyyaml, each where its format is read or written) and layer 0 (`sonardet`, `sonardet.geometry`).
"""
