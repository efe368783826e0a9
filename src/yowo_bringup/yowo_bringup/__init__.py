"""YOWO bag replay node, yowo command line, launch files, evaluation and report."""
