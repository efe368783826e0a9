"""YOWO CMC processing: agent keypoint tracking per ceiling camera, co-visibility groups, incremental SfM, group BA."""
