"""YOWO collaborative processing: rebalanced Umeyama, scene keypoints in CMC views, joint factor graph, isolated CMCs."""
