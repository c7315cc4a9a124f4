"""SITL for companion: a simulated MAVLink multirotor and a facade camera with ground truth.

Only sim/ may read ground truth; the companion sees the vehicle through MAVLink and the camera through frames.
"""
