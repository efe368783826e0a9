"""Shared geometry, camera model and message conversions of YOWO (no rclpy here)."""
