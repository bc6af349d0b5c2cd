"""The least-squares solution of the fusion, arc by arc (docs/sca_fusion.md)."""
