"""Estimators: the generic batched Kalman primitives and the transfer-alignment filter."""

from qkf.filters.transfer_alignment import FilterParams, FilterRecord, TransferAlignmentKF

__all__ = ["FilterParams", "FilterRecord", "TransferAlignmentKF"]
