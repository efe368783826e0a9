"""YOWO synthetic capture generator with ground truth."""
