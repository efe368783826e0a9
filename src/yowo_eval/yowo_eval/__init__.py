"""YOWO evaluation and benchmark (metrics, bound, baselines); never imported by the runtime packages."""
