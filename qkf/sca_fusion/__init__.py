"""Star-camera + angular-accelerometer attitude fusion by batch least squares
(docs/sca_fusion.md)."""
