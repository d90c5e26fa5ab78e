"""Assimilation loops, the bounded L-BFGS wrapper, logging and checkpoints."""
