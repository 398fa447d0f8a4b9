"""Synthetic optical captures with exact ground truth.

A skinned body (procedural sweep body or the MakeHuman rig) moves through a built-in
clip or any BVH; soft tissue adds what skinning cannot explain; markers ride on the
skin; a camera model decides what is seen, breaks trajectories and adds noise and
ghosts; a simulated rope joins the point cloud. Every stage keeps the truth.
"""
