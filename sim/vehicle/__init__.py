"""Simulated multirotor autopilot that speaks MAVLink 2 over UDP like PX4 SITL (or, optionally, ArduCopter).

The companion talks to it only through MAVLink; its true pose goes out on a separate local UDP channel that only
the simulated camera reads.
"""
