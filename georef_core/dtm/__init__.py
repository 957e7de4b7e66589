"""Bare-earth DTM from the dense step's DSM and point cloud (docs/deliverables.md, "Bare-earth DTM").

* :mod:`.ground_filter` ground / non-ground of the DSM cells (progressive morphological filter)
* :mod:`.bare_earth` the DTM raster: non-ground cells removed and interpolated, its mask, a hide-and-refill check
* :mod:`.removed_objects` what was removed: connected regions, their area and height
* :mod:`.point_classes` ASPRS classes of the dense points against the DTM

The step that runs them on a run folder is :mod:`georef_core.steps.dtm` (``georef dtm OUT_DIR``).
"""
