"""Keyframes in other tools' own forms (``companion export``): a COLMAP workspace."""
