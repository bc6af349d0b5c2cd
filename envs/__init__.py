"""Gymnasium environments of qkf (SPEC §5), registered as ``qkf/...``.

The transfer-alignment environment wraps :class:`qkf.filters.TransferAlignmentKF`; it arrives
with the Gymnasium issue. The package exists now so that the layout is stable.
"""
