"""Batched closed loops: N worlds in lockstep as compiled code over arrays."""
