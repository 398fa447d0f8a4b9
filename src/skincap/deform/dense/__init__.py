"""Dense-marker skin animation after Park & Hodgins 2006, §5.

Registration of a body mesh to the marker surface (:mod:`.registration`), near-rigid
segmentation of the marker surface (:mod:`.segmentation`), marker and vertex part
weights (:mod:`.weights`), local part frames (:mod:`.parts`) and the rigid + quadratic +
RBF deformation of the vertices (:mod:`.deformer`).
"""
