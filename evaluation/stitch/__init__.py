"""Synthetic keyframe spools with exact truth, and the map measured against the wall's texture."""
