"""YOWO ego-camera processing: RGB-D odometry, multiway registration, feature tracks, bundle adjustment, rectification, point cloud."""
