"""Simulated devices that speak the real protocols (pseudo-terminals, loopback TCP) and a
simulated camera that renders the sample and writes DNG files."""
