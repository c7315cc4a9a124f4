"""companion: UAV facade-inspection companion app (plan, fly, mask, cull, stitch)."""

__version__ = "0.1.0"
