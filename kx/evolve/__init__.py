"""Composing learners and the simulator: policies from genomes, population evaluation, the run loop."""
