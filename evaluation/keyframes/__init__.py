"""Synthetic wall views with exact overlap truth, and the gate measured against a recording's truth."""
