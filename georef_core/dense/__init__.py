"""Dense reconstruction from oriented images: pair selection, rectified semi-global matching, multi-view
depth fusion into a coloured point cloud, DSM and true-orthophoto rasters, LAS/LAZ output.

The step function is :func:`georef_core.steps.dense.run_dense`; docs/dense.md describes the method.
Modules (one job each):

* ``camera_views``: an oriented image as a scaled pinhole + distortion view (projection, rays, loading).
* ``sparse_prior``: depth ranges of the scene from the sparse points, or from ORB matches triangulated
  with the known poses when the oriented images carry none.
* ``pair_selection``: stereo partners per reference image (overlap, baseline/depth ratio, view angle).
* ``rectified_stereo``: rectification of a pair, semi-global matching, disparity -> depth in the
  reference view.
* ``depth_fusion``: multi-view consistency filtering of the depth maps and fusion into points.
* ``point_cloud_filter``: surface outlier removal (vectorised, 2.5-D) and voxel thinning (Open3D).
* ``dsm_raster``: robust binning of the points into a DSM, harmonic hole filling and flagging.
* ``orthophoto``: true orthophoto from the DSM and the images (occlusion test, most-nadir view).
* ``cog_writer``: Cloud-Optimized GeoTIFF writing.
* ``point_cloud_io``: LAS/LAZ with the CRS.
* ``dsm_compare``: a DSM against a reference DSM (RMSE, median, completeness).
* ``ortho_check``: checkerboard targets located in an orthophoto against their surveyed positions.
* ``preview``: quick-look PNGs (hillshaded DSM, orthophoto thumbnail).
"""
