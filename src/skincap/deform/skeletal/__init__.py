"""Skeleton-driven skinning: binding, automatic weights, retargeting, LBS and DQS.

The contract every piece keeps: a :class:`~skincap.types.Motion` on the skin's own
skeleton gives, by forward kinematics, joint world transforms ``W (T, J, 4, 4)``;
the skinning matrices are ``W @ skin.inverse_bind``; in the bind pose they are the
identity. Deformers turn skinning matrices into vertex positions.
"""
