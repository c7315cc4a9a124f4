"""SITL for companion: a simulated MAVLink multirotor and a facade camera with ground truth.

Only sim/ may read ground truth; the companion sees the vehicle through MAVLink and the camera through frames.
"""

from sim.providers import register as _register_providers

_register_providers()
