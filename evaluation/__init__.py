"""Evaluation of the product against known truth: synthetic walls and spools, the gate's, the mask's and the map's
evaluators, and where the real photographs are.

Used by the benches, the tests and the simulator's ``eval`` commands; the product (``companion``) never imports it
(tests/test_dependencies.py), so nothing here can change what a flight, a cull or a stitch does.
"""
