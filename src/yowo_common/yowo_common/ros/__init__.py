"""Helpers that need rclpy (serialization, QoS). Algorithm modules never import this package."""
