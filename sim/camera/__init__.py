"""Simulated facade camera with ground truth: scene, renderer, true overlap, recordings and the live camera.

Only sim/ and evaluations read ground truth; the companion sees frames only.
"""
