"""The onboard chain: capture -> tag -> depth mask -> overlap gate -> spool, live during flight or offline."""
